#!/bin/bash
# Session 13 plan b (one H100): drive cameras developed on the card (render_exposed) vs the host model (478ccb3),
# 150 m each, then 1 km with them; render rate again (contact sheet drawn while frames render).
LOG=/root/logs_b; mkdir -p $LOG
exec > $LOG/plan.out 2>&1
set -x
cd /root/rt
. /root/roadtwin-stage/unpack.sh
B=$PYTHONPATH
export PYTHONPATH=/root/rt:/root/rt/plugins:$B PYTHONUNBUFFERED=1
mkdir -p /root/old && tar xzf /root/rt/.dev_rt/old.tgz -C /root/old
nvidia-smi > $LOG/nvidia.txt 2>&1; nproc >> $LOG/nvidia.txt
t0=$(date +%s)
[ -f /root/town/town.usda ] || python3 -m roadtwin_core.cli compose stages/town.usda -o /root/town > $LOG/compose_town.log 2>&1
python3 bench/synthetic_set.py --scenes highway_a --phase compose --no-photo --no-road-textures --weights pothole=2,crack=12 --frames 10 -o /root/hw > $LOG/compose_hw.log 2>&1
echo "compose hw $(( $(date +%s) - t0 )) s" >> $LOG/times.txt
H=/root/hw/scenes/highway_a/town/town.usda
python3 bench/drive.py $H --length 150 --device cuda --render-device cuda > $LOG/drive_150m_new.txt 2>&1
echo "150 new $(( $(date +%s) - t0 )) s" >> $LOG/times.txt
PYTHONPATH=/root/old:/root/old/plugins:$B python3 bench/drive.py $H --length 150 --device cuda --render-device cuda > $LOG/drive_150m_old.txt 2>&1
echo "150 old $(( $(date +%s) - t0 )) s" >> $LOG/times.txt
for r in 1 2; do
  python3 bench/render_throughput.py --stage /root/town/town.usda --device cuda --frames 3000 --warmup 8 > $LOG/rt_new_$r.txt 2>&1
  echo "rt new $r $(( $(date +%s) - t0 )) s" >> $LOG/times.txt
done
nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used --format=csv -l 5 > $LOG/smi_drive.csv 2>&1 & SMI=$!
python3 bench/drive.py $H --length 1000 --device cuda --render-device cuda > $LOG/drive_1km_new.txt 2>&1
kill $SMI
echo "drive 1km $(( $(date +%s) - t0 )) s" >> $LOG/times.txt
touch $LOG/DONE
