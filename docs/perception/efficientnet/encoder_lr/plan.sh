#!/bin/bash
# Session 14 plan d (one H100): the ImageNet encoder kept closer to its weights (--encoder-lr 0.1, the 0.1x encoder rate
# of DeepLab / DAFormer, chosen before any run, not swept) on the 5,000-frame parametric set (five highways x 1,000,
# --weights pothole=2,crack=12 --no-photo, photo road surfaces): zero-shot seeds 0, 1 with and without it on this one
# machine; and 100 % real (a) and (c) 0.5 constant with it, seed 0. 4,500 steps every run; six runs at once.
LOG=/root/logs_e; mkdir -p $LOG
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
R="--real /root/real --synthetic /root/np/synthetic --seeds 0"
$P suite $R 1 --arms e --parallel 2 --out /root/e_base > $LOG/e_base.txt 2>&1 &
$P suite $R 1 --arms e --parallel 2 --encoder-lr 0.1 --out /root/e_elr > $LOG/e_elr.txt 2>&1 &
$P suite $R --arms a c --mix 0.5:constant --fractions 1 --parallel 2 --encoder-lr 0.1 --out /root/ac_elr > $LOG/ac_elr.txt 2>&1 &
wait; stamp "trained"
for d in e_base e_elr ac_elr; do mkdir -p $LOG/$d; cp /root/$d/*.json $LOG/$d/; cp -r /root/$d/logs $LOG/$d/run_logs; done
cp /root/np/synthetic_set.json $LOG/ 2>/dev/null
touch $LOG/DONE
