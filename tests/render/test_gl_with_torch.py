"""Rendering and training in one process: torch's CUDA wheels bring triton, whose LLVM
crashed the process when loaded after Mesa's llvmpipe (`dashtraj.render.gl`)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import textwrap

import pytest


def test_gl_context_then_torch_optimizer_does_not_crash(gl_available):
    # find_spec, not importorskip: importing triton here, after the session's GL context,
    # would be the crash itself without the fix
    if importlib.util.find_spec("triton") is None or importlib.util.find_spec("torch") is None:
        pytest.skip("needs torch with triton (the training extra with torch's CUDA wheel)")
    code = textwrap.dedent("""
        import numpy as np
        from dashtraj.render.gl import create_context
        ctx = create_context()
        fbo = ctx.simple_framebuffer((16, 16)); fbo.use(); ctx.clear(1.0, 0.0, 0.0)
        assert np.frombuffer(fbo.read(), np.uint8)[:3].tolist() == [255, 0, 0]
        import torch
        torch.optim.AdamW(torch.nn.Linear(2, 2).parameters())  # imports torch._dynamo, triton
        print("ok")
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == "ok", (r.returncode, r.stderr[-2000:])
