#!/bin/bash
# Session 15 plan (one H100): zero-shot's encoder rate chosen on the real TRAIN frames (which (e) never
# trains on; --select), never on val: shares 1, 0.3, 0.1, seeds 0 and 1, the 5,000-frame parametric set
# made again as in plans d-f. 4,500 steps every run; six runs at once. Rule fixed before: the share with
# the highest mIoU on train (seeds pooled) is zero-shot's recommended setting; val reported for all.
LOG=/root/logs_h; mkdir -p $LOG
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
SSET=/root/np bash $G compose --scenes $S --weights pothole=2,crack=12 --no-photo > $LOG/compose_np.txt 2>&1; stamp "composed rc=$?"
SSET=/root/np FRAMES=1000 bash $G render $S > $LOG/render_np.txt 2>&1; stamp "rendered rc=$?"
P="python3 bench/perception.py"
R="--real /root/real --synthetic /root/np/synthetic --select /root/real/train"
for share in 1 0.3 0.1; do
  $P suite $R --seeds 0 1 --arms e --parallel 2 --encoder-lr $share --out /root/sel_e$share > $LOG/sel_e$share.txt 2>&1 &
done
wait; stamp "trained"
for share in 1 0.3 0.1; do d=sel_e$share; mkdir -p $LOG/$d; cp /root/$d/*.json $LOG/$d/; cp -r /root/$d/logs $LOG/$d/run_logs; done
touch $LOG/DONE
