"""Same seed, same output on any x86-64 processor: two BLAS kernels, one result.

OpenBLAS picks a kernel per processor, and a matrix product may round the same row
differently on two machines (docs/ARCHITECTURE.md, "Floating point across processors").
``kernel_probe.py`` runs seeded syntheses in a fresh process under the machine's own kernel and under a forced generic one
(``OPENBLAS_CORETYPE=Prescott``, which every x86-64 processor runs); every coordinate must
agree within 1e-6 m and every geometry must be valid under both.
"""
import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

PROBE = Path(__file__).resolve().parent / "kernel_probe.py"


def _probe(tmp_path, coretype):
    env = dict(os.environ)
    env.pop("OPENBLAS_CORETYPE", None)
    if coretype:
        env["OPENBLAS_CORETYPE"] = coretype
    out = tmp_path / f"{coretype or 'native'}.npz"
    run = subprocess.run([sys.executable, str(PROBE), str(out)], env=env, capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    return np.load(out)


@pytest.mark.skipif(platform.machine() != "x86_64", reason="OpenBLAS core types of x86-64")
def test_same_output_under_two_blas_kernels(tmp_path):
    native, generic = _probe(tmp_path, None), _probe(tmp_path, "Prescott")
    assert set(native.files) == set(generic.files)
    for name in native.files:
        a, b = native[name], generic[name]
        assert a.shape == b.shape, name
        assert len(a) > 100, name
        assert np.abs(a - b).max() < 1e-6, name
