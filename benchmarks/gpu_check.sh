#!/bin/bash
# The checks that need a GPU, in one run: the detector's and the renderer's tests with the
# CUDA array backend and the EGL renderer, then bench-detector (NumPy against torch:cuda)
# and bench-render on EGL. Run from the repository root on a machine with an NVIDIA GPU,
# PyTorch with CUDA, libEGL and the package's Python dependencies; figures and logs go to
# $1 (default reports/gpu). Nothing here runs in CI, which has no GPU.
set -u
out=${1:-reports/gpu}
mkdir -p "$out"
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
export PYTHONUNBUFFERED=1
# The tests' conftest sets OSMesa only where nothing is set: these tests render over EGL.
export PYOPENGL_PLATFORM=egl
status=0

nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv | tee "$out/gpu.txt"
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())" \
    | tee -a "$out/gpu.txt"

python3 -m pytest -q -p no:cacheprovider -rs test/detector test/test_pipeline.py \
    test/test_photometric.py test/render 2>&1 | tee "$out/pytest.log"
[ "${PIPESTATUS[0]}" -eq 0 ] || status=1

python3 -m benchmarks.detector --frames 100 --array-backends numpy,torch:cuda \
    --out "$out/bench_detector.json" 2>&1 | tee "$out/bench_detector.log"
[ "${PIPESTATUS[0]}" -eq 0 ] || status=1

python3 -m benchmarks.render --backend egl --out "$out/bench_render.json" 2>&1 \
    | tee "$out/bench_render.log"
[ "${PIPESTATUS[0]}" -eq 0 ] || status=1

exit $status
