"""Test-session set-up: headless rendering and single-threaded math before anything imports MuJoCo."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# One OpenBLAS kernel family on every x86-64 machine (AVX2 + FMA, which any machine CI runs on has). OpenBLAS
# picks its kernels by CPU at load time, and kernels of different families round small matrix products
# (the experts' IK) differently in the last bit: the pinned behaviour digests (tests/test_behaviour_digest.py)
# differed between an Intel AVX-512 machine (SkylakeX kernels) and an AMD one (Zen kernels). Must be set
# before numpy is first imported; subprocesses of the tests inherit it.
os.environ.setdefault("OPENBLAS_CORETYPE", "Haswell")
os.environ.setdefault("HF_HUB_OFFLINE", "1")
