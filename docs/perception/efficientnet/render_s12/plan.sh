#!/bin/bash
# Session 12 device plan b (one H100): render rate new (3cabcaf) / mid (4a60d9c) / old (c250727), then the 1 km drive.
LOG=/root/logs; mkdir -p $LOG
exec > $LOG/plan.out 2>&1
set -x
cd /root/rt
. /root/roadtwin-stage/unpack.sh
BASE=$PYTHONPATH
export PYTHONPATH=/root/rt:/root/rt/plugins:$BASE PYTHONUNBUFFERED=1
nvidia-smi > $LOG/nvidia.txt 2>&1; nproc >> $LOG/nvidia.txt
t0=$(date +%s)
python3 -m roadtwin_core.cli compose stages/town.usda -o /root/town > $LOG/compose_town.log 2>&1
echo "compose town $(( $(date +%s) - t0 )) s" >> $LOG/times.txt
rt() {  # name, code root
  PYTHONPATH=$2:$2/plugins:/root/rt:/root/rt/plugins:$BASE python3 bench/render_throughput.py --stage /root/town/town.usda --device cuda --frames 3000 --warmup 8 > $LOG/rt_$1.txt 2>&1
  echo "rt $1 $(( $(date +%s) - t0 )) s" >> $LOG/times.txt
}
rt new_1 /root/rt; rt old_1 /root/old; rt mid_1 /root/mid; rt new_2 /root/rt; rt old_2 /root/old; rt mid_2 /root/mid; rt new_3 /root/rt
python3 bench/synthetic_set.py --scenes highway_a --phase compose --no-photo --no-road-textures --weights pothole=2,crack=12 --frames 10 -o /root/hw > $LOG/compose_hw.log 2>&1
echo "compose hw $(( $(date +%s) - t0 )) s" >> $LOG/times.txt
nvidia-smi --query-gpu=timestamp,utilization.gpu,memory.used --format=csv -l 5 > $LOG/smi_drive.csv 2>&1 & SMI=$!
python3 bench/drive.py /root/hw/scenes/highway_a/town/town.usda --length 1000 --device cuda --render-device cuda > $LOG/drive_1km_h100.txt 2>&1
kill $SMI
echo "drive done $(( $(date +%s) - t0 )) s" >> $LOG/times.txt
touch $LOG/DONE
