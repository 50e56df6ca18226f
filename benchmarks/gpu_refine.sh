#!/bin/bash
# Seven shipped range models refined at once on one GPU, each on its own box from its own weights (measured in
# docs/BENCHMARKS.md, "Seven refinements on a GPU"). On the device machine, from the repository root, wheels for the
# packages its image lacks (pytorch-optimizer, soundfile, cffi, pycparser, mido: `pip download --only-binary=:all:
# --python-version 3.12 --platform manylinux_2_28_x86_64 --no-deps -d build/wheels ...`, or WHEELS=DIR) carried there:
#     bash benchmarks/gpu_refine.sh MINUTES [cuda|cpu]      # the models and logs come back in $OUT/models.tgz
# The core is built there by CMake for that Python. cpu (with PY=.venv/bin/python, STEPS='--steps 2') runs the same
# here, for a check.
MIN=${1:-7}; DEV=${2:-cuda}; PY=${PY:-python3}; OUTDIR=${OUT:-/tmp/gpuout}; M=/tmp/m; mkdir -p $M $OUTDIR
export PYTHONPATH=$PWD OMP_NUM_THREADS=2
if [ "$DEV" = cuda ]; then
  $PY -m pip install --no-deps --no-index -q ${WHEELS:-build/wheels}/*.whl 2>&1 | tail -2
  rm -f bowsynth/_core*.so
  (cmake -S . -B /tmp/core -G Ninja -DCMAKE_BUILD_TYPE=Release -DPython_EXECUTABLE=$(command -v $PY) > /tmp/cmake.log 2>&1 && cmake --build /tmp/core -j16 >> /tmp/cmake.log 2>&1) || tail -20 /tmp/cmake.log
  cp $(find /tmp/core -name "_core*.so" | head -1) bowsynth/
  nvidia-smi --query-gpu=name,memory.used --format=csv
fi
$PY -c "import bowsynth.compiled as c; c.load(); import torch; print('core ok', torch.__version__, torch.cuda.is_available())"
job() {  # name: its recipe gives the box, width and windows; refined from its shipped weights
  local name=$1
  timeout 570 $PY -m bowsynth train --config models/$name.toml --from models/$name.safetensors \
    --batch 4096 --seed 35 --device $DEV --minutes $MIN $STEPS --out $M/$name-g.safetensors -q > $M/$name-g.log 2>&1
  echo "$name rc=$?" >> $M/$name-g.log
}
for name in soft-range soft-high soft-top slow-soft velocity-soft stick-low stick-slow; do job $name & done
sleep 60; nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv
wait
tail -n 3 $M/*.log
tar czf $OUTDIR/models.tgz -C $M $(cd $M && ls *.safetensors *.log)
ls -la $OUTDIR
