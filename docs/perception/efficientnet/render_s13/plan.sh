#!/bin/bash
# Session 13 plan a (one H100): render rate end to end, new (parallel planning + meta a frame a line) vs old (478ccb3).
LOG=/root/logs; mkdir -p $LOG
exec > $LOG/plan.out 2>&1
set -x
cd /root/rt
. /root/roadtwin-stage/unpack.sh
B=$PYTHONPATH
export PYTHONPATH=/root/rt:/root/rt/plugins:$B PYTHONUNBUFFERED=1
mkdir -p /root/old && tar xzf /root/rt/.dev_rt/old.tgz -C /root/old
nvidia-smi > $LOG/nvidia.txt 2>&1; nproc >> $LOG/nvidia.txt
t0=$(date +%s)
python3 -m roadtwin_core.cli compose stages/town.usda -o /root/town > $LOG/compose_town.log 2>&1
echo "compose town $(( $(date +%s) - t0 )) s" >> $LOG/times.txt
rt() {  # name, code root
  PYTHONPATH=$2:$2/plugins:$B python3 bench/render_throughput.py --stage /root/town/town.usda --device cuda --frames 3000 --warmup 8 > $LOG/rt_$1.txt 2>&1
  echo "rt $1 $(( $(date +%s) - t0 )) s" >> $LOG/times.txt
}
rt new_1 /root/rt; rt old_1 /root/old; rt new_2 /root/rt; rt old_2 /root/old; rt new_3 /root/rt; rt old_3 /root/old
PYTHONPATH=/root/rt:/root/rt/plugins:$B python3 bench/render_throughput.py --stage /root/town/town.usda --device cuda --frames 6000 --warmup 8 > $LOG/rt_new_6000.txt 2>&1
echo "rt new 6000 $(( $(date +%s) - t0 )) s" >> $LOG/times.txt
touch $LOG/DONE
