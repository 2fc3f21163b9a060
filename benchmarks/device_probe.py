"""The device probe: takes the project to a GPU machine with no network, runs its device tests and prints every figure
of the device issue, each section under its own timeout, writing what it has as it goes.

Two steps. Here, on a machine with a package registry (once; the wheels are ignored by git):

    python benchmarks/device_probe.py prepare        # wheels for Python 3.12, manylinux x86-64, into .whl/

There (the lent machine has Python 3.12 with torch and JAX's CUDA build; ``$OUT`` is where figures are kept), one
command, at most about 12 minutes at the sections' limits (45, 120, 120, 120, 90, 80, 80 and 60 s; a lent machine's
call is at most 10: run some sections with ``--only``, the least measured first), carrying ``.whl`` and
``.gl`` (EGL's libraries as Debian packages, for the endoscope's section):

    for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig; \
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
      && PYTHONPATH=/tmp/site:. python3 benchmarks/device_probe.py run --out "$OUT"

Sections (each a process of its own with its own time limit; one that fails or runs out says so and the next runs;
``--only NAME ...`` runs some alone):

1. ``machine``: the GPU's name and memory, JAX's and torch's devices, the commit;
2. ``jax_trainer``: ``benchmarks/device_training.py``, the JAX trainer on the large-batch configuration
   (``baselines/configs/suction_debris_mappo_large_batch.toml``) at 4,096 worlds, validated by eight validators at
   once, for the time to 0.9 validation success; ``jax_speed``: its cycle's speed per N;
3. ``tests``: the device tests on the GPU (``tests/test_device_env.py``, ``tests/test_backends.py``,
   ``tests/test_streams.py`` and the JAX trainer's determinism over many steps; ``DVRL_MARL_TEST_DEVICE=cuda``);
4. ``speed_1m``, ``speed``, ``speed_benchmark``: ``benchmarks/device_speed.py`` on the GPU, the sim alone and with a
   torch policy's inference, N = 1,048,576, then 1,024 to 262,144 with the defaults and 16,384 and 262,144 with the
   benchmark's setting, the numpy env beside it up to N = 4,096;
5. ``endoscope``: ``benchmarks/endoscope_speed.py``, image observations at 84 x 84 through the batched step on the
   GPU's EGL, 1,024 and 4,096 worlds drawn by 1 to 16 GL contexts in threads, beside a bare ``mujoco.Renderer``
   (the libraries EGL needs travel as ``.gl/``, the device tool's README says how; MuJoCo's import needs them too,
   ``MUJOCO_GL=egl`` being set for every section); ``endoscope_tests``: ``tests/test_endoscope.py`` there.

Figures land in ``$OUT/probe.jsonl`` (one JSON line each) and ``$OUT/probe.log``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: What the lent machine lacks (its image has numpy, torch, JAX, pytest, hypothesis, typing-extensions, absl-py,
#: etils, cloudpickle): what importing the env needs. MuJoCo 4 comes in parts: ``mujoco`` is the front,
#: ``mujoco-core`` the bindings and the renderer; ``mujoco-studio`` (the viewer, with Filament) is never imported here.
#: The trainer's models are TorchRL's (its compiled extension is optional; tensordict's links no torch).
WHEELS = ("pydantic", "pydantic-core", "annotated-types", "typing-inspection", "array-api-compat", "gymnasium",
          "farama-notifications", "pettingzoo", "mujoco", "mujoco-core", "pyopengl", "glfw", "torchrl", "tensordict",
          "pyvers", "hoptorch", "orjson", "importlib-metadata", "optax")
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_27_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64",
             "manylinux1_x86_64", "any")


def prepare(folder: Path) -> int:
    """Download the wheels of :data:`WHEELS`, at the versions installed here, for Python 3.12 on x86-64 Linux."""
    from importlib import metadata

    folder.mkdir(exist_ok=True)
    status = 0
    for name in WHEELS:
        try:
            version = metadata.version(name)
        except metadata.PackageNotFoundError:
            print(f"{name}: not installed here; install the project's extras first", file=sys.stderr)
            status = 1
            continue
        command = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:",
                   "--python-version", "3.12", "--implementation", "cp", "-d", str(folder), f"{name}=={version}"]
        for platform in PLATFORMS:
            command += ["--platform", platform]
        done = subprocess.run(command, check=False, capture_output=True, text=True)
        print(f"{name}=={version}: {'ok' if done.returncode == 0 else done.stderr.strip().splitlines()[-1]}")
        status |= done.returncode != 0
    size = sum(f.stat().st_size for f in folder.glob("*.whl")) / 2**20
    print(f"{folder}: {len(list(folder.glob('*.whl')))} wheels, {size:.1f} MiB (a call carries at most 64 MiB)")
    return status


def _section(name: str, command: list[str], timeout: float, log, env=None) -> int:
    began = time.perf_counter()
    log(f"=== {name} (at most {timeout:.0f} s): {' '.join(command)}")
    try:
        done = subprocess.run(command, check=False, capture_output=True, text=True, timeout=timeout, cwd=ROOT,
                              env={**os.environ, **(env or {})})
        log(done.stdout[-6000:] + (("\n" + done.stderr[-3000:]) if done.returncode else ""))
        status = done.returncode
    except subprocess.TimeoutExpired as expired:
        out = expired.stdout.decode() if isinstance(expired.stdout, bytes) else (expired.stdout or "")
        log(out[-6000:] + f"\n{name}: stopped at its limit of {timeout:.0f} s")
        status = 124
    log(f"=== {name}: exit {status} after {time.perf_counter() - began:.0f} s")
    return status


def run(out: Path, device: str = "cuda", only: list[str] | None = None) -> int:
    out.mkdir(parents=True, exist_ok=True)
    figures, log_file = out / "probe.jsonl", (out / "probe.log").open("a")

    def log(text: str) -> None:
        print(text, flush=True)
        log_file.write(text + "\n")
        log_file.flush()

    env = {"XLA_PYTHON_CLIENT_PREALLOCATE": "false", "PYTHONUNBUFFERED": "1", "MUJOCO_GL": "egl"}
    vendor = Path("/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json")  # (the lent machine's EGL driver)
    if vendor.is_file():
        env["__EGL_VENDOR_LIBRARY_FILENAMES"] = str(vendor)
    python = sys.executable
    machine = ("import json, jax, torch; print(json.dumps({'torch': torch.__version__, 'jax': jax.__version__, "
               "'gpu': torch.cuda.get_device_name(0) if torch.cuda.is_available() else None, "
               "'memory_gib': round(torch.cuda.get_device_properties(0).total_memory / 2**30, 1) "
               "if torch.cuda.is_available() else None, 'jax_devices': [str(d) for d in jax.devices()]}))")
    gpu = device != "cpu"  # (cpu: a dry run of the script, small sizes)
    speed = [python, "benchmarks/device_speed.py", "--device", device, "--json", str(figures), "--repeats", "2"]
    trainer = [python, "benchmarks/device_training.py", "--device", device, "--json", str(figures)]
    large = ["--config", "baselines/configs/suction_debris_mappo_large_batch.toml"]
    sections = {  # name: (command, time limit in seconds, extra environment), the least measured first
        "machine": ([python, "-c", machine], 45, {}),
        # the trainer compiled whole (dvrl_marl.training.jax_mappo) on the large-batch configuration at 4,096 worlds:
        # a curriculum of 512 batches, validated every 32 by eight validators at once, for the time to the target
        "jax_trainer": (trainer + large + ["--validators", "8" if gpu else "1", "--worlds",
                                           "4096" if gpu else "64", "--total-steps", "67108864" if gpu else "131072",
                                           "--eval-every", "4194304" if gpu else "65536",
                                           "--seconds", "100" if gpu else "60"], 150, {}),
        # its cycle's speed per N (sim alone in a compiled loop; whole update cycles), compilation timed apart
        "jax_speed": ([python, "benchmarks/jax_trainer_speed.py", "--device", device, "--json", str(figures),
                       "--sizes", *(["4096", "16384", "65536", "262144"] if gpu else ["64"])], 150, {}),
        # (the trainer's tests on the GPU: its run on the compiled env; the others are the CPU's)
        "tests": ([python, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-x", "tests/test_device_env.py",
                   "tests/test_backends.py", "tests/test_streams.py",
                   "tests/test_jax_mappo.py::test_the_compiled_cycle_is_deterministic_over_many_steps"], 120,
                  {"DVRL_MARL_TEST_DEVICE": device}),
        # (a size per process: each N compiles its own step)
        "speed_1m": (speed + ["--sizes", "1048576" if gpu else "2048"], 90, {}),
        "speed": (speed + ["--sizes", *(["1024", "16384", "262144"] if gpu else ["64", "1024"])], 80, {}),
        "speed_benchmark": (speed + ["--preset", "benchmark", "--sizes", *(["16384", "262144"] if gpu else
                                                                           ["1024"])], 80, {}),
        # (1 to 16 GL contexts, each in a thread of its own: the driver's CPU work per drawing bounds one)
        "endoscope": ([python, "benchmarks/endoscope_speed.py", "--sizes", "84", "--worlds",
                       *(["1024", "4096"] if gpu else ["16"]), "--contexts", *(["1", "2", "4", "8", "16"] if gpu else
                                                                               ["1", "2"]),
                       "--frames", "8192" if gpu else "64", "--repeats", "2", "--json", str(figures)], 150, {}),
        # the images' tests on the GPU's EGL (the composite is the whole scene drawn at once; the contexts' images)
        "endoscope_tests": ([python, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_endoscope.py"], 150,
                            {}),
    }
    unknown = sorted(set(only or ()) - set(sections))
    if unknown:
        raise SystemExit(f"--only: no section {', '.join(unknown)}; the sections: {', '.join(sections)}")
    statuses = {}
    for name, (command, limit, extra) in sections.items():
        if not only or name in only:
            statuses[name] = _section(name, command, limit, log, {**env, **extra})
    log("probe: " + json.dumps(statuses))
    return 0 if all(status == 0 for status in statuses.values()) else 1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("prepare", help="download the wheels the lent machine lacks into .whl/").add_argument(
        "--folder", default=str(ROOT / ".whl"))
    runner = commands.add_parser("run", help="on the lent machine: tests and figures")
    runner.add_argument("--out", required=True)
    runner.add_argument("--device", default="cuda", help="cuda (default); cpu: a dry run of the script here")
    runner.add_argument("--only", nargs="+", metavar="SECTION", help="run these sections alone (a second call)")
    args = parser.parse_args()
    sys.exit(prepare(Path(args.folder)) if args.command == "prepare" else run(Path(args.out), args.device, args.only))


if __name__ == "__main__":
    main()
