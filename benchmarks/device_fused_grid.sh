#!/usr/bin/env bash
# The fused grid march (swim.rt.march_pallas) on a lent GPU: the script to give the `device` tool
# (docs/decisions/0006-gpu-kernels.md). Run from the repository root there, with the wheels swim needs beyond that
# machine's image in .whl/ and the Katrina file in .devdata/wrf_katrina/ (both carried). STAGE=compare (the default):
# the 1024^2 all-sky views with the fused kernel, each scene's captured chunk against the kernels in $AGAINST (default:
# the lockstep loops and "fused-march"); STAGE=profile (~260 s): where a warm frame's time goes (bench_gpu.py
# --profile), more block shapes, and the README's render in two new processes (the second reads the exported program
# with its Triton call); STAGE=table (docs/decisions/0006-gpu-kernels.md; ~340 s on a fresh H100, of which ~140 s
# compilations, so the adaptive and new-sun rows need SYNTHETIC_S=420): the synthetic 1024^2 all-sky's captured chunk
# with "fused" against "fused-march", and warm frames with the camera's rays kept on the device
# (ExecutionSettings.ray_table, swim.rt.ray_table) against without, taking turns: every pixel, adaptive and a new sun
# every frame; STAGE=step1a (docs/decisions/0006-gpu-kernels.md; ~200 s): the tests of a new sun's Step 1a on the
# device, then frames with a new sun each with and without it; STAGE=sampler (docs/decisions/0005-adaptive-sampling.md;
# ~300 s on a fresh machine): the device sampler's tests, then adaptive frames with the sampler on the device against
# the host's; STAGE=readme (~100 s): the README's render in two new processes; STAGE=next (a fresh machine's first
# run, ~300 s): STAGE=sampler, to be followed on the warm machine by STAGE=second and STAGE=readme; STAGE=second
# (~330 s on the warm machine): STAGE=step1a with its tests cut short, then Nsight Compute's counters of the fused
# kernel.
# STAGE=blocks (docs/decisions/0006-gpu-kernels.md; ~300 s on a fresh machine): the captured chunk of the synthetic
# 1024^2 all-sky with the fused kernel's variants, each against the render's kernel: first the fused multiply-adds,
# alone and with the register caps; 128 x 4 capped at 168 and 128 registers (the same occupancy as 512 x 16 with
# 128-ray lockstep; benchmarks/pallas_registers.py: 512 rays x 16 warps caps ptxas at 128 registers, twice the
# occupancy of 128 x 4's 255, with 88 bytes of spills; 512 x 16 left out: 128 x 4 at 128 registers has its occupancy
# with less lockstep); and a scalar gather per table channel (ExecutionSettings.fused_vector_loads off).
# STAGE=image (docs/decisions/0006-gpu-kernels.md; ~200 s on the warm machine after STAGE=blocks): the tests of the
# image finished on the device (ExecutionSettings.device_image: its planes and colour there), then warm frames with it
# against without, taking turns, every pixel and adaptive, and a wall-clock profile of each with it. STAGE=parts
# (docs/decisions/0005-adaptive-sampling.md; ~240 s): benchmarks/frame_parts.py, each of a warm frame's programs
# waited for, every pixel and adaptive. STAGE=first (a fresh machine's first run, ~560 s): STAGE=blocks, then
# STAGE=parts; then STAGE=image on the warm machine. Results go to $OUT/results.tar.gz (the device tool returns at
# most 8 files).
#
# Preparing the carried folders here (both are in .git/info/exclude):
#   for p in netCDF4 cftime pvlib pytz colour-science; do python3 -m pip download -q --no-deps --only-binary=:all: \
#       --python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 \
#       --platform manylinux2014_x86_64 --platform manylinux1_x86_64 -d .whl $p; done
#   mkdir -p .devdata/wrf_katrina && cp ../shared/data/wrf_katrina/ci_test_file.nc .devdata/wrf_katrina/
# then: device run "STAGE=compare bash benchmarks/device_fused_grid.sh" with carry [".whl", ".devdata"] (~330 s of
# device time with a fresh machine's compilations; STAGE=profile takes ~260 s).
set -u
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD/src PYTHONUNBUFFERED=1 SWIM_CACHE_DIR=/tmp/swim-cache SWIM_PRECOMPILE=0
OUT=${OUT:-/tmp/out}
RES=/tmp/results
mkdir -p "$OUT" "$RES"
save() { tar -C "$RES" -czf "$OUT/results.tar.gz" . ; }  # after each stage too: a run killed at its limit keeps what it made
trap 'save; ls -la "$RES"' EXIT
quiet() { grep -v "^WARNING\|^I0000\|absl"; }
nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.max.sm --format=csv
python3 -c "import jax, numpy, numba; print('jax', jax.__version__, jax.devices(), 'numpy', numpy.__version__, 'numba', numba.__version__)"
step1a() {  # ExecutionSettings.step1a_on_device (docs/decisions/0006-gpu-kernels.md), ~200 s: its tests on the GPU first (the
    # donating program runs only there; where the machine has pytest), then frames with a new sun each, taking turns
    timeout "${TESTS_S:-150}" python3 -m pytest -q -p no:cacheprovider -k "not numba" tests/unit/rt/test_rt_solar_device.py 2>&1 | tail -3 || true
    timeout "${SYNTHETIC_S:-300}" python3 benchmarks/bench_gpu.py --scenes synthetic --data .devdata --step1a-on-device \
        --sun-series 3 --repeats 4 --out "$RES/step1a-synthetic.json" 2>&1 | quiet
    # the two paths' fields and the step classes that they flip (docs/decisions/0007-scene-set-up.md), on the GPU's
    # JAX (~60 s)
    timeout "${PATHS_S:-120}" python3 benchmarks/step1a_paths.py --sun 31.5 138 2>&1 | grep -v Warning | tee "$RES/step1a-paths.txt" | tail -5
}
readme() {  # the README's render at 1024^2 in two new processes (the second reads the first's caches)
    for k in 1 2; do
        t0=$(date +%s.%N)
        timeout 150 python3 -m swim.cli.main render --size 1024 --out "$RES/readme-$k.png" 2>&1 | quiet
        echo "README render at 1024^2, new process $k: $(python3 -c "import sys, time; print(f'{time.time() - float(sys.argv[1]):.2f}')" "$t0") s"
    done
}
sampler() {  # ExecutionSettings.device_sampling (docs/decisions/0005-adaptive-sampling.md), ~300 s on a fresh machine: its tests on the GPU, then adaptive
    # frames with the sampler on the device against the host's, taking turns (the ray table on for both; the images
    # compared there, so the tests that render, which would compile the march here first, are left out)
    timeout "${TESTS_S:-120}" python3 -m pytest -q -p no:cacheprovider -k "not rendered_scene and not render_with" tests/unit/rt/test_rt_image_sampling_device.py 2>&1 | tail -3 || true
    timeout "${SAMPLER_S:-260}" python3 benchmarks/bench_gpu.py --scenes synthetic --data .devdata --device-sampling \
        --repeats 5 --out "$RES/sampler-synthetic.json" 2>&1 | quiet
}
kernel_counters() {  # Nsight Compute's counters of the fused kernel ("swim_fused_march") in a warm
    # machine's 1024^2 all-sky of the synthetic scene (its programs in the caches): registers, occupancy, where its
    # warps stall, memory and issue throughput; the second launch only (with three launches the profiler can lose
    # the process on the second: one launch after the first goes through)
    mkdir -p "$RES/ncu-run"
    timeout "${NCU_S:-150}" ncu --clock-control none -k regex:swim_fused --launch-skip 1 --launch-count 1 --section LaunchStats \
        --section Occupancy --section SpeedOfLight --section WarpStateStats --section ComputeWorkloadAnalysis \
        --section MemoryWorkloadAnalysis --section SchedulerStats python3 benchmarks/bench_gpu.py --scenes synthetic \
        --data .devdata --repeats 1 --out "$RES/ncu-run/ncu-run.json" > "$RES/ncu-synthetic.txt" 2>&1
    grep -v "^WARNING\|^I0000\|absl" "$RES/ncu-synthetic.txt" | grep -i "swim_fused\|Registers\|Occupancy\|Throughput\|Stall\|Duration\|Eligible\|Issued\|Block Size\|Grid Size\|Warp Cycles\|Hit Rate\|Local" | head -80
}
blocks() {  # the fused kernel's variants (docs/decisions/0006-gpu-kernels.md), each against the render's kernel (its
    # tables read four channels a load): "f" fused multiply-adds (ExecutionSettings.fused_fma), "rN" at most N
    # registers per thread (PTX's .maxnreg: 168 fits three 128-ray programs per SM, 128 four, against two), "s" a
    # scalar gather per channel (ExecutionSettings.fused_vector_loads off); most telling first, each line printed as it
    # is timed (the JSON is written at the end)
    timeout "${BLOCKS_S:-330}" python3 benchmarks/bench_gpu.py --scenes synthetic --data .devdata --repeats 3 \
        --fused-blocks ${BLOCKS:-128x4f 128x4r168 128x4r168f 128x4s 128x4r128 128x4r128f} \
        --out "$RES/blocks-synthetic.json" 2>&1 | quiet
    # should this JAX's Pallas not lower the vector loads (checked with JAX 0.10.2 only,
    # docs/decisions/0006-gpu-kernels.md), the render's kernel with scalar gathers, and the caps with them
    [ -s "$RES/blocks-synthetic.json" ] || timeout "${BLOCKS_S:-330}" python3 benchmarks/bench_gpu.py --scenes synthetic \
        --data .devdata --repeats 3 --scalar-loads --fused-blocks 128x4sf 128x4r168s 128x4r168sf \
        --out "$RES/blocks-synthetic-scalar.json" 2>&1 | quiet
}
image() {  # ExecutionSettings.device_image (docs/decisions/0006-gpu-kernels.md): its tests on the GPU (the colour stage's float64
    # on the device), then warm frames with the image finished on the device against the host, taking turns, and
    # where a new process's README render (its caches warm) spends its ~11 s (docs/decisions/0006-gpu-kernels.md)
    timeout "${TESTS_S:-60}" python3 -m pytest -q -p no:cacheprovider tests/unit/color/test_color_device.py 2>&1 | tail -3 || true
    timeout "${IMAGE_S:-260}" python3 benchmarks/bench_gpu.py --scenes synthetic --data .devdata --device-image \
        --repeats 5 --out "$RES/image-synthetic.json" 2>&1 | quiet
    save
    readme_profile
}
parts() {  # docs/decisions/0005-adaptive-sampling.md: each program of a warm 1024^2 frame waited for, every pixel and adaptive (the
    # march, the table's rows, the sampler's tests, splits, scatters and fill, the planes, the colour stage), the rest
    # the host's; the first render compiles (~85 s on a fresh H200)
    timeout "${PARTS_S:-240}" python3 benchmarks/frame_parts.py --data .devdata --repeats 3 --profile \
        --out "$RES/frame-parts-synthetic.json" 2>&1 | quiet
}
readme_profile() {  # the README's render at 1024^2 in a new process twice (the first fills the caches), the second
    # under cProfile: the top functions by cumulative time to readme-profile.txt
    timeout 150 python3 -m swim.cli.main render --size 1024 --out "$RES/readme-1.png" 2>&1 | quiet
    t0=$(date +%s.%N)
    timeout 150 python3 -m cProfile -o "$RES/readme-2.prof" -m swim.cli.main render --size 1024 --out "$RES/readme-2.png" 2>&1 | quiet
    echo "README render at 1024^2 under cProfile, new process 2: $(python3 -c "import sys, time; print(f'{time.time() - float(sys.argv[1]):.2f}')" "$t0") s"
    python3 -c "import pstats, sys; s = pstats.Stats(sys.argv[1]); s.sort_stats('cumulative').print_stats(45); s.sort_stats('tottime').print_stats(25)" \
        "$RES/readme-2.prof" > "$RES/readme-profile.txt" 2>&1
    head -70 "$RES/readme-profile.txt"
}
if [ "${STAGE:-compare}" = blocks ]; then
    blocks
elif [ "${STAGE:-compare}" = parts ]; then
    parts
elif [ "${STAGE:-compare}" = first ]; then  # a fresh machine's first run (~560 s)
    BLOCKS_S=${BLOCKS_S:-300} blocks; save
    parts
elif [ "${STAGE:-compare}" = image ]; then
    image
elif [ "${STAGE:-compare}" = second ]; then  # a second run on the warm machine (~330 s): STAGE=step1a, its
    # tests cut short, then the fused kernel's counters
    TESTS_S=${TESTS_S:-45} SYNTHETIC_S=${SYNTHETIC_S:-170} step1a; save
    kernel_counters
elif [ "${STAGE:-compare}" = next ]; then  # a fresh machine's first run (~300 s): the sampler on the device; then, on
    # the warm machine, STAGE=second (~330 s) and the README's render (STAGE=readme)
    sampler
elif [ "${STAGE:-compare}" = readme ]; then  # the README's render in two new processes, the ray table on by default
    # (docs/decisions/0006-gpu-kernels.md)
    readme
elif [ "${STAGE:-compare}" = sampler ]; then
    sampler
elif [ "${STAGE:-compare}" = step1a ]; then
    step1a
elif [ "${STAGE:-compare}" = table ]; then
    timeout "${SYNTHETIC_S:-330}" python3 benchmarks/bench_gpu.py --scenes synthetic --data .devdata --against fused-march \
        --ray-table --sampling --sun-series 3 --out "$RES/table-synthetic.json" 2>&1 | quiet
elif [ "${STAGE:-compare}" = compare ]; then
    timeout "${SYNTHETIC_S:-330}" python3 benchmarks/bench_gpu.py --scenes synthetic --data .devdata --against ${AGAINST:-lockstep fused-march} \
        --fused-blocks ${BLOCKS:-64x2 256x8} --sampling --out "$RES/fused-synthetic.json" 2>&1 | quiet
    timeout "${KATRINA_S:-150}" python3 benchmarks/bench_gpu.py --scenes katrina --data .devdata --against ${AGAINST:-lockstep fused-march} \
        --sampling --out "$RES/fused-katrina.json" 2>&1 | quiet
else
    timeout "${SYNTHETIC_S:-240}" python3 benchmarks/bench_gpu.py --scenes synthetic --data .devdata --profile \
        --sampling --fused-blocks ${BLOCKS:-256x4 128x2} --out "$RES/profile-synthetic.json" 2>&1 | quiet
    readme
    ls "$SWIM_CACHE_DIR"/* | head -20
fi
