#!/usr/bin/env python3
"""Set up cam2sim on first use in a project-local environment, then run the demo or the tests.

    python3 quickstart.py demo [DEMO OPTIONS]   # e.g. python3 quickstart.py demo -o /tmp/demo
    python3 quickstart.py test [PYTEST OPTIONS] # lint, type-check and every test

Needs only Python 3.11+ and the package registries. The first run creates ``.venv`` beside this
file (``CAM2SIM_ENV`` names another folder) and installs into it:

- PyTorch: on a machine with an NVIDIA driver (``nvidia-smi`` answers) the CUDA build and gsplat
  (the GPU splat rasterizer, compiled on first use); otherwise the CPU build (from PyTorch's CPU
  index, falling back to PyPI), so pip does not pull gigabytes of CUDA wheels.
- cam2sim (editable) with the extras the command needs: the pipeline's for ``demo``; also the
  test tools and Ray for ``test``.
- For ``test``: Debian's Chromium for the editor's browser tests, where this user may install it
  (root, or sudo without a password); elsewhere those tests are skipped, and it says so.

Later runs reuse the environment; it is refreshed when ``pyproject.toml`` changes. Only the
standard library is used here.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
TORCH = "torch==2.13.0"
TORCH_CPU_INDEX = "https://download.pytorch.org/whl/cpu"
PIPELINE = "map,splat,metrics,detect,scenario,sim,ads"
EXTRAS = {"demo": PIPELINE, "test": f"test,{PIPELINE},ray"}
STAMP = "cam2sim-quickstart.json"
CHROMIUM = Path("/usr/bin/chromium")


def say(text: str) -> None:
    """One line of progress."""
    print(f"quickstart: {text}", flush=True)


def run(*cmd: str | Path, check: bool = True) -> int:
    """Run a command in the foreground; its exit code (raises on failure when ``check``)."""
    return subprocess.run([str(c) for c in cmd], check=check).returncode


def env_dir() -> Path:
    """The project-local environment's folder."""
    return Path(os.environ.get("CAM2SIM_ENV", ROOT / ".venv")).resolve()


def env_python(env: Path) -> Path:
    """The environment's Python."""
    return env / ("Scripts/python.exe" if os.name == "nt" else "bin/python")


def has_cuda() -> bool:
    """Whether an NVIDIA driver answers (then the CUDA build of torch and gsplat are wanted)."""
    smi = shutil.which("nvidia-smi")
    if smi is None:
        return False
    return subprocess.run([smi, "-L"], capture_output=True, check=False).returncode == 0


def wanted(command: str, cuda: bool) -> dict[str, str]:
    """What ``command`` needs installed (the stamp written after installing it)."""
    digest = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    return {"pyproject": digest, "extras": EXTRAS[command], "cuda": str(cuda), "torch": TORCH}


def installed(env: Path) -> dict[str, str]:
    """The stamp of what was installed in ``env`` ({} when nothing was)."""
    try:
        data = json.loads((env / STAMP).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def covers(have: dict[str, str], want: dict[str, str]) -> bool:
    """Whether what is installed serves ``want`` (the test extras include the demo's)."""
    same = all(have.get(k) == want[k] for k in ("pyproject", "cuda", "torch"))
    extras = set(have.get("extras", "").split(","))
    return same and set(want["extras"].split(",")) <= extras


def install(env: Path, want: dict[str, str], cuda: bool) -> None:
    """Create ``env`` if needed and install torch, cam2sim and its extras into it."""
    if not env_python(env).is_file():
        say(f"creating the environment {env}")
        venv.EnvBuilder(with_pip=True).create(env)
    py = env_python(env)
    run(py, "-m", "pip", "install", "--quiet", "--upgrade", "pip")
    if cuda:
        say(f"NVIDIA driver found: installing {TORCH} (CUDA build) from PyPI")
        run(py, "-m", "pip", "install", "--quiet", TORCH)
    else:
        say(f"no NVIDIA driver: installing the CPU build of {TORCH}")
        cpu = (py, "-m", "pip", "install", "--quiet", "--retries", "0", "--timeout", "20")
        if run(*cpu, TORCH, "--index-url", TORCH_CPU_INDEX, check=False) != 0:
            say("PyTorch's CPU index is out of reach; installing torch from PyPI instead")
            run(py, "-m", "pip", "install", "--quiet", TORCH)
    extras = want["extras"] + (",splat-cuda" if cuda else "")
    say(f"installing cam2sim with [{extras}]")
    run(py, "-m", "pip", "install", "--quiet", "-e", f"{ROOT}[{extras}]")
    (env / STAMP).write_text(json.dumps(want, indent=2), encoding="utf-8")


def ensure_chromium() -> None:
    """Debian's Chromium for the browser tests, where this user may install it."""
    if CHROMIUM.is_file():
        return
    apt = shutil.which("apt-get")
    if apt is None:
        say(f"no apt-get: the editor's browser tests will be skipped ({CHROMIUM} missing)")
        return
    if os.geteuid() == 0:
        prefix: list[str] = []
    elif shutil.which("sudo") and run("sudo", "-n", "true", check=False) == 0:
        prefix = ["sudo", "-n"]
    else:
        say(
            f"the editor's browser tests will be skipped: {CHROMIUM} is missing and installing "
            "it needs root (sudo apt-get install chromium)"
        )
        return
    say("installing Debian's Chromium for the editor's browser tests")
    environ = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for args in (["update", "-qq"], ["install", "-y", "-qq", "chromium"]):
        done = subprocess.run([*prefix, apt, *args], env=environ, check=False, capture_output=True)
        if done.returncode != 0:
            say("could not install Chromium; the editor's browser tests will be skipped")
            return


def main(argv: list[str]) -> int:
    """Set up, then run the demo or the checks; the exit code."""
    if sys.version_info < (3, 11):
        say(f"cam2sim needs Python 3.11 or newer; this is {sys.version.split()[0]}")
        return 1
    if not argv or argv[0] not in EXTRAS:
        print(__doc__.split("\n\n")[1] if __doc__ else "usage: quickstart.py demo|test")
        return 2
    command, rest = argv[0], argv[1:]
    env = env_dir()
    cuda = has_cuda()
    want = wanted(command, cuda)
    if not covers(installed(env), want):
        install(env, want, cuda)
    py = env_python(env)
    if command == "demo":
        return run(py, "-m", "cam2sim", "demo", *(rest or ["-o", "cam2sim-demo"]), check=False)
    ensure_chromium()
    os.chdir(ROOT)
    checks = (["ruff", "check", "."], ["ruff", "format", "--check", "."], ["mypy"])
    for step in checks:
        say(" ".join(step))
        if run(py, "-m", *step, check=False) != 0:
            return 1
    say("lint-imports (the package layers)")
    if run(env / "bin" / "lint-imports", check=False) != 0:
        return 1
    say("pytest")
    return run(py, "-m", "pytest", "-q", "-p", "no:cacheprovider", *rest, check=False)


if __name__ == "__main__":
    try:
        sys.exit(main(sys.argv[1:]))
    except subprocess.CalledProcessError as err:
        say(f"{' '.join(map(str, err.cmd))} failed (exit {err.returncode}); see its output above")
        sys.exit(1)
    except KeyboardInterrupt:
        say("interrupted; run the same command again to go on")
        sys.exit(130)
