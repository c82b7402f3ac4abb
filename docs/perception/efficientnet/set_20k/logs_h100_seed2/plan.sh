#!/bin/bash
# Session 14 plan c (one H100, after plan b): the 20,000-frame set's missing third seed, mixed 0.5 constant at 100 % and
# 10 % real (seed 2; the set_20k section's seeds 0 and 1 ran on an H200), 4,500 steps.
LOG=/root/logs_s2; mkdir -p $LOG
exec > $LOG/plan.out 2>&1
set -x
cd /root/rt
stamp(){ echo "$(date +%T) $*" >> $LOG/times.txt; }
stamp start
. /root/roadtwin-stage/unpack.sh
export PYTHONPATH=/root/rt:/root/rt/plugins:$PYTHONPATH PYTHONUNBUFFERED=1
python3 bench/perception.py suite --real /root/real --synthetic /root/p20/synthetic --arms c --mix 0.5:constant --fractions 1 0.1 --seeds 2 --parallel 2 --out /root/r20s2 > $LOG/c_p20_s2.txt 2>&1; stamp "mixed seed 2 rc=$?"
cp /root/r20s2/*.json $LOG/ 2>/dev/null; cp -r /root/r20s2/logs $LOG/run_logs 2>/dev/null
touch $LOG/DONE
