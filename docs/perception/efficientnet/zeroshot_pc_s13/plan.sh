#!/bin/bash
# Session 13 plan c (one H100): zero-shot (e) on the photo-crack set (parametric potholes, crack assets from the photo
# library of all 600 train_full frames, procedural road surfaces), seeds 0 and 1, 4,500 steps: the set s12 could not
# compose (54-62 GB); now with the CDT merger's bounded refinement.
LOG=/root/logs_pc; mkdir -p $LOG
exec > $LOG/plan.out 2>&1
set -x
cd /root/rt
stamp(){ echo "$(date +%T) $*" >> $LOG/plan.log; }
stamp start
mkdir -p /root/real /root/photos
tar xf /root/stage_pc/real.tar -C /root/real
cat /root/stage_pc/photos.part0* | tar xf - -C /root/photos
. /root/roadtwin-stage/unpack.sh
export PYTHONPATH=/root/rt:/root/rt/plugins:$PYTHONPATH PYTHONUNBUFFERED=1
( while true; do ps -eo rss,args --sort=-rss | grep "cli compose" | grep -v grep | head -1 | awk '{print $1}' >> $LOG/compose_rss_kb.txt; sleep 5; done ) & MON=$!
S="highway_a highway_b highway_c highway_d highway_e"
G=docs/perception/efficientnet/gpu_synthetic.sh
export JOBS=5 WORKERS=3
SSET=/root/pc bash $G compose --scenes $S --weights pothole=2,crack=12 --photo-types crack --no-road-textures > $LOG/compose_pc.txt 2>&1; stamp "composed pc rc=$?"
kill $MON; sort -n $LOG/compose_rss_kb.txt | tail -1 >> $LOG/plan.log
SSET=/root/pc FRAMES=1000 bash $G render $S > $LOG/render_pc.txt 2>&1; stamp "rendered pc rc=$?"
python3 bench/perception.py suite --real /root/real --arms e --seeds 0 1 --parallel 2 --synthetic /root/pc/synthetic --out /root/s_e_pc > $LOG/e_pc.txt 2>&1; stamp "e_pc rc=$?"
stamp "all done"
touch $LOG/DONE
