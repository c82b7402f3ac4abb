#!/bin/bash
# Session 14 plan b (one H100): zero-shot (e) on 20,000 parametric frames (the set_20k recipe: five highways x 4,000
# frames, --weights pothole=2,crack=12 --no-photo, photo road surfaces), seeds 0 and 1, 4,500 steps: do four times
# the frames move zero-shot (issue 22's target; 5,000 frames gave pothole 8.2-12.7, crack 14.3-17.1)?
LOG=/root/logs_z; mkdir -p $LOG
exec > $LOG/plan.out 2>&1
set -x
cd /root/rt
stamp(){ echo "$(date +%T) $*" >> $LOG/times.txt; }
stamp start
mkdir -p /root/real && tar xf /root/stage_z/real.tar -C /root/real
rm -rf /root/photo_surfaces && cp -r /root/stage_z/photo_surfaces /root/photo_surfaces
. /root/roadtwin-stage/unpack.sh
export PYTHONPATH=/root/rt:/root/rt/plugins:$PYTHONPATH PYTHONUNBUFFERED=1
S="highway_a highway_b highway_c highway_d highway_e"
G=docs/perception/efficientnet/gpu_synthetic.sh
SSET=/root/p20 FRAMES=4000 bash $G compose --scenes $S --weights pothole=2,crack=12 --no-photo > $LOG/compose_p20.txt 2>&1; stamp "composed rc=$?"
SSET=/root/p20 FRAMES=4000 bash $G render $S > $LOG/render_p20.txt 2>&1; stamp "rendered rc=$?"
python3 bench/perception.py suite --real /root/real --arms e --seeds 0 1 --parallel 2 --synthetic /root/p20/synthetic --out /root/z20 > $LOG/e_p20.txt 2>&1; stamp "zero-shot rc=$?"
cp /root/p20/synthetic_set.json $LOG/ 2>/dev/null; cp /root/z20/*.json $LOG/ 2>/dev/null; cp -r /root/z20/logs $LOG/run_logs 2>/dev/null
touch $LOG/DONE
