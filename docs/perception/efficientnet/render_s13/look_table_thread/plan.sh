#!/bin/bash
# Session 13 plan d (one H100): render rate end to end with 1d2... (look table on a thread), 3 runs, 3,000 frames.
LOG=/root/logs_d; mkdir -p $LOG
exec > $LOG/plan.out 2>&1
set -x
cd /root/rt
. /root/roadtwin-stage/unpack.sh
export PYTHONPATH=/root/rt:/root/rt/plugins:$PYTHONPATH PYTHONUNBUFFERED=1
nvidia-smi > $LOG/nvidia.txt 2>&1; nproc >> $LOG/nvidia.txt
t0=$(date +%s)
python3 -m roadtwin_core.cli compose stages/town.usda -o /root/town > $LOG/compose_town.log 2>&1
echo "compose town $(( $(date +%s) - t0 )) s" >> $LOG/times.txt
for r in 1 2 3; do
  python3 bench/render_throughput.py --stage /root/town/town.usda --device cuda --frames 3000 --warmup 8 > $LOG/rt_new_$r.txt 2>&1
  echo "rt new $r $(( $(date +%s) - t0 )) s" >> $LOG/times.txt
done
touch $LOG/DONE
