"""Download the wheels the lent accelerator machine lacks, for its Python 3.12 on x86-64, into the
git-ignored folder ``.whl/`` of the checkout (at most 60 MiB in all: the working tree that travels
to that machine is limited to 64 MiB).

That machine's image has JAX with CUDA, flax, optax, orbax-checkpoint, chex, numpy, scipy,
tensorstore and protobuf, but not the packages below; nothing can be installed there from a
registry. warp-lang (≈ 150 MB) cannot travel: the ``warp`` backend is the one thing that needs it.
The versions are the ones installed here (what the suite ran against), else ``PINS``.

    python bench/device_wheels.py            # -> .whl/*.whl and the command to run on the machine

The command (docs/research/scaling.md "The accelerator run"), with ``.whl`` carried:

    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \\
        --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:$PWD || exit
    PYTHONUNBUFFERED=1 python3 bench/accelerator.py --out $OUT
"""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import subprocess
import sys

# What the project imports that the machine lacks (the MuJoCo engine's bindings and MJX, the Brax env
# API and what brax imports at `import brax.envs`, the replay library, TensorBoard writing), with
# the versions to take where this Python has none installed. mujoco-studio (the viewer) is not
# imported; pyopengl only renders.
PINS = {
    "mujoco": "4.0.1", "mujoco-core": "4.0.1", "mujoco-mjx": "3.17.0", "brax": "0.14.2",
    "flashbax": "0.1.3", "glfw": "2.11.0", "jaxopt": "0.8.5", "trimesh": "5.2.0", "tensorboardX": "2.6.5",
}
LIMIT_MIB = 60
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_27_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64",
             "manylinux1_x86_64")
DEVICE_COMMAND = ("python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade "
                  "--target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:$PWD || exit; "
                  "PYTHONUNBUFFERED=1 python3 bench/accelerator.py --out $OUT")


def wanted() -> dict:
    """``{distribution: version}``: this Python's installed version of each, else its pin."""
    out = {}
    for name, pin in PINS.items():
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = pin
    return out


def download(versions: dict, folder: str, python_version: str = "3.12") -> None:
    """``pip download`` each ``name==version`` (binary wheels alone, no dependencies) for CPython
    ``python_version`` on manylinux x86-64 into ``folder``."""
    platforms = [a for p in PLATFORMS for a in ("--platform", p)]
    for name, version in versions.items():
        cmd = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:",
               "--python-version", python_version, "--implementation", "cp", *platforms, "-d", folder,
               f"{name}=={version}"]
        subprocess.run(cmd, check=True)


def folder_mib(folder: str) -> float:
    return sum(os.path.getsize(os.path.join(folder, f)) for f in os.listdir(folder)) / 2**20


def main(argv=None) -> int:
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--dir", default=os.path.join(root, ".whl"), help="where the wheels go (default: the checkout's .whl/)")
    args = p.parse_args(argv)
    os.makedirs(args.dir, exist_ok=True)
    stale = [f for f in os.listdir(args.dir) if f.endswith(".whl")]
    versions = wanted()
    keep = {f"{n.replace('-', '_').lower()}-{v}" for n, v in versions.items()}
    for f in stale:  # two versions of one package would stop the install there
        if not any(f.lower().startswith(k + "-") for k in keep):
            os.remove(os.path.join(args.dir, f))
    download(versions, args.dir)
    size = folder_mib(args.dir)
    for f in sorted(os.listdir(args.dir)):
        print(f"{os.path.getsize(os.path.join(args.dir, f)) / 2**20:7.2f} MiB  {f}")
    print(f"{size:7.2f} MiB in all (limit {LIMIT_MIB} MiB)")
    if size > LIMIT_MIB:
        print(f"error: the wheels take {size:.1f} MiB, more than the {LIMIT_MIB} MiB that may travel", file=sys.stderr)
        return 1
    print("on the machine (carry .whl):\n  " + DEVICE_COMMAND)
    return 0


if __name__ == "__main__":
    sys.exit(main())
