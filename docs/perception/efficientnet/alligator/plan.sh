#!/bin/bash
# Session 16 (one H100, the session's last ~8 min of device time): does a twin with alligator
# (fatigue) crack areas, the crack road_defects_br labels, find more real crack? Two 1,000-frame
# parametric sets (five highways x 200), the second with --weights alligator=6 beside
# pothole=2,crack=12; zero-shot seed 0 on each, 1,500 steps (750 + 750: the time left), evaluated on
# val and on the train frames (--select: zero-shot never trains on them, and a parametric set holds
# none of their labels). Rule fixed before: alligator goes into the zero-shot recipe if train crack IoU
# rises with its interval above 0 and train mIoU does not fall. One seed, a short schedule: a screen.
LOG=${LOG:-/root/logs_k}; mkdir -p $LOG
exec > $LOG/plan.out 2>&1
set -x
stamp(){ echo "$(date +%T) $*" >> $LOG/times.txt; }
stamp start
mkdir -p /root/real /root/wheels && tar xf /root/stage_z/real.tar -C /root/real
rm -rf /root/photo_surfaces && cp -r /root/stage_z/photo_surfaces /root/photo_surfaces
. /root/roadtwin-stage/unpack.sh
export PYTHONPATH=$PWD:$PWD/plugins:$PYTHONPATH PYTHONUNBUFFERED=1
nvidia-smi > $LOG/nvidia.txt 2>&1
S="highway_a highway_b highway_c highway_d highway_e"
G=docs/perception/efficientnet/gpu_synthetic.sh
SSET=/root/nb FRAMES=200 bash $G compose --scenes $S --weights pothole=2,crack=12 --no-photo > $LOG/compose_nb.txt 2>&1 &
SSET=/root/na FRAMES=200 bash $G compose --scenes $S --weights pothole=2,crack=12,alligator=6 --no-photo > $LOG/compose_na.txt 2>&1 &
wait; stamp "composed"
SSET=/root/nb FRAMES=200 bash $G render $S > $LOG/render_nb.txt 2>&1; stamp "rendered nb rc=$?"
SSET=/root/na FRAMES=200 bash $G render $S > $LOG/render_na.txt 2>&1; stamp "rendered na rc=$?"
P="python3 bench/perception.py"
for s in nb na; do
  $P suite --real /root/real --synthetic /root/$s/synthetic --select /root/real/train --seeds 0 --arms e --parallel 1 \
    --pretrain-steps 750 --steps 750 --out /root/z_$s > $LOG/z_$s.txt 2>&1 &
done
wait; stamp "trained"
for s in nb na; do mkdir -p $LOG/z_$s; cp /root/z_$s/*.json $LOG/z_$s/; cp -r /root/z_$s/logs $LOG/z_$s/run_logs; done
mkdir -p $LOG/frames; for s in nb na; do ls /root/$s/synthetic/images | head -400 | awk 'NR%80==1' | while read f; do cp /root/$s/synthetic/images/$f $LOG/frames/${s}_$f; cp /root/$s/synthetic/labels/${f%.*}.png $LOG/frames/${s}_${f%.*}_label.png; done; done
for s in nb na; do python3 bench/label_stats.py /root/$s/synthetic/labels --every 5 > $LOG/label_stats_$s.txt 2>&1; done
touch $LOG/DONE
