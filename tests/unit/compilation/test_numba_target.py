"""The instruction set of swim's numba kernels (swim.compilation.numba_target): AVX-512 left out on Intel CPUs that have it,
the user's settings kept, and a target that numba set up before swim left alone."""

import json
import os
import subprocess
import sys

import pytest

pytest.importorskip("numba")

from swim.compilation.numba_target import features_without_avx512, has_avx512, is_avx512_feature  # noqa: E402


def test_every_avx512_feature_is_switched_off_and_the_others_kept_in_order():
    features = "+64bit,+avx2,+avx512f,-sse4a,+avx512vl,+fma,+avx512bf16,-avx10.1,+avx10.2,+evex512,-amx-avx512,+amx-tile"
    assert features_without_avx512(features) == (
        "+64bit,+avx2,-avx512f,-sse4a,-avx512vl,+fma,-avx512bf16,-avx10.1,-avx10.2,-evex512,-amx-avx512,+amx-tile")


def test_no_feature_after_the_change_switches_avx512_on_again():
    # LLVM applies features in order: a "+avx512vl" left after "-avx512f" would switch it back on
    changed = features_without_avx512("+avx512f,+avx512vl,+avx512dq,+avx2")
    assert not [item for item in changed.split(",") if item.startswith("+") and is_avx512_feature(item[1:])]
    assert has_avx512("+avx2,+avx512f") and not has_avx512(changed) and not has_avx512("+avx2,-avx512f")


def test_features_named_like_avx512_but_not_it_are_kept():
    assert not is_avx512_feature("avx2") and not is_avx512_feature("avxvnni") and not is_avx512_feature("amx-tile")
    assert features_without_avx512("") == ""


def _fresh(code, **env_changes):
    """Run ``code`` in a fresh interpreter with swim's numba settings unset except ``env_changes``; its last line of
    output, parsed as JSON."""
    env = {k: v for k, v in os.environ.items() if k not in ("SWIM_NUMBA_AVX512", "NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")}
    env.update(env_changes)
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])


_STATE = ("import json, numba, llvmlite.binding as b; from numba.core.codegen import get_host_cpu_features; "
          "import swim.rt.march_cpu as m; f = m._march_ray_range.targetctx.codegen().magic_tuple()[2]; "
          "print(json.dumps({'host': get_host_cpu_features(), 'name': b.get_host_cpu_name(), 'used': f}))")


def test_the_kernels_compile_for_the_host_less_avx512_on_intel():
    state = _fresh(_STATE)
    if has_avx512(state["host"]) and not state["name"].startswith("znver"):
        assert state["used"] == features_without_avx512(state["host"])
    else:  # nothing to leave out (or an AMD core): numba's own choice
        assert state["used"] == state["host"]


@pytest.mark.full  # two new processes: the full tier (the host's default is tested above)
def test_swim_numba_avx512_1_keeps_numbas_choice_and_0_leaves_it_out_everywhere():
    kept = _fresh(_STATE, SWIM_NUMBA_AVX512="1")
    assert kept["used"] == kept["host"]
    left_out = _fresh(_STATE, SWIM_NUMBA_AVX512="0")
    assert left_out["used"] == features_without_avx512(left_out["host"])


@pytest.mark.full  # a new process: the full tier
def test_the_users_numba_cpu_settings_are_kept():
    state = _fresh(_STATE, NUMBA_CPU_FEATURES="+avx2,+fma,+avx512f", SWIM_NUMBA_AVX512="0")
    assert state["used"] == "+avx2,+fma,+avx512f"


@pytest.mark.full  # a new process: the full tier
def test_a_target_set_up_before_swims_kernels_is_left_alone():
    code = ("import numba; numba.njit(lambda x: x + 1)(1); " + _STATE)
    state = _fresh(code, SWIM_NUMBA_AVX512="0")
    assert state["used"] == state["host"]


@pytest.mark.perf  # an inspection of the compiled code
def test_compiled_code_has_no_avx512_instructions_where_avx512_is_left_out():
    # a vectorised loop with a condition and a gather: with AVX-512, LLVM uses its mask registers (k1-k7) and its
    # extra vector registers (16-31), which only EVEX-encoded (AVX-512) instructions address
    code = ("import json, re, numpy as np, numba; import swim.rt.march_cpu\n"
            "@numba.njit(fastmath=True)\n"
            "def f(a, table, index):\n"
            "    s = 0.0\n"
            "    for n in range(a.shape[0]):\n"
            "        if a[n] > 0.0:\n"
            "            s += a[n] * table[index[n]]\n"
            "    return s\n"
            "f(np.ones(64), np.ones(8, np.float32), np.zeros(64, np.int64))\n"
            "asm = next(iter(f.inspect_asm().values()))\n"
            "evex = re.findall(r'%zmm[0-9]+|%k[1-7]\\b|%[xy]mm(?:1[6-9]|2[0-9]|3[01])\\b', asm)\n"
            "print(json.dumps({'evex': len(evex), 'ymm': asm.count('%ymm'), "
            "'avx512': '+avx512f' in f.targetctx.codegen().magic_tuple()[2]}))")
    kept = _fresh(code, SWIM_NUMBA_AVX512="1")
    if not kept["avx512"]:
        pytest.skip("this CPU has no AVX-512")
    left_out = _fresh(code, SWIM_NUMBA_AVX512="0")
    assert kept["evex"] > 0, "with AVX-512, the loop uses its mask or upper vector registers"
    assert left_out["evex"] == 0 and left_out["ymm"] > 0, "without it, AVX2's 256-bit registers only"
