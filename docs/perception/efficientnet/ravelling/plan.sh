#!/bin/bash
# Session 15 plan b (one H100): does a twin with ravelled wheel-path strips labelled pothole (the
# ravelling type; road_defects_br's RS_290 labels such strips pothole: 95 % of train's pothole pixels)
# find the real strips? Two 1,000-frame parametric sets (five highways x 200), the same but for
# --weights ravelling=2; zero-shot seed 0 on each, 2,250 steps (1125 + 1125), evaluated on val and on
# the train frames (--select: zero-shot never trains on them). Rule fixed before: the strips go in the
# recipe if train pothole IoU rises with its interval above 0 and train mIoU does not fall.
LOG=/root/logs_i; mkdir -p $LOG
exec > $LOG/plan.out 2>&1
set -x
cd /root/rt
stamp(){ echo "$(date +%T) $*" >> $LOG/times.txt; }
stamp start
mkdir -p /root/real /root/wheels && tar xf /root/stage_z/real.tar -C /root/real
rm -rf /root/photo_surfaces && cp -r /root/stage_z/photo_surfaces /root/photo_surfaces
. /root/roadtwin-stage/unpack.sh
export PYTHONPATH=/root/rt:/root/rt/plugins:$PYTHONPATH PYTHONUNBUFFERED=1
nvidia-smi > $LOG/nvidia.txt 2>&1
S="highway_a highway_b highway_c highway_d highway_e"
G=docs/perception/efficientnet/gpu_synthetic.sh
SSET=/root/nb FRAMES=200 bash $G compose --scenes $S --weights pothole=2,crack=12 --no-photo > $LOG/compose_nb.txt 2>&1 &
SSET=/root/nr FRAMES=200 bash $G compose --scenes $S --weights pothole=2,crack=12,ravelling=2 --no-photo > $LOG/compose_nr.txt 2>&1 &
wait; stamp "composed"
SSET=/root/nb FRAMES=200 bash $G render $S > $LOG/render_nb.txt 2>&1; stamp "rendered nb rc=$?"
SSET=/root/nr FRAMES=200 bash $G render $S > $LOG/render_nr.txt 2>&1; stamp "rendered nr rc=$?"
P="python3 bench/perception.py"
for s in nb nr; do
  $P suite --real /root/real --synthetic /root/$s/synthetic --select /root/real/train --seeds 0 --arms e --parallel 1 \
    --pretrain-steps 1125 --steps 1125 --out /root/z_$s > $LOG/z_$s.txt 2>&1 &
done
wait; stamp "trained"
for s in nb nr; do mkdir -p $LOG/z_$s; cp /root/z_$s/*.json $LOG/z_$s/; cp -r /root/z_$s/logs $LOG/z_$s/run_logs; done
for s in nb nr; do python3 bench/label_stats.py /root/$s/synthetic/labels --every 5 > $LOG/label_stats_$s.txt 2>&1; done
mkdir -p $LOG/frames; for s in nb nr; do ls /root/$s/synthetic/images | head -400 | awk 'NR%50==1' | while read f; do cp /root/$s/synthetic/images/$f $LOG/frames/${s}_$f; cp /root/$s/synthetic/labels/${f%.*}.png $LOG/frames/${s}_${f%.*}_label.png; done; done
touch $LOG/DONE
