import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering in CI
