"""Pack what a GPU machine without a package registry needs to run mop: one .tar.xz of a site directory.

    python benchmarks/gpu_bundle.py --out .gpu/site.tar.xz

The GPU machines lent here have PyTorch and a scientific stack preinstalled (IMAGE below, read from
the workplace's device notes) but reach no package index. This packs every other distribution that
mop, its tests and DVC need, resolved from this virtual environment's installed metadata:

- pure-Python distributions are copied from this environment's site-packages (they run on any
  Python 3 version);
- compiled ones are downloaded as CPython ``--python`` wheels of the same version (``pip download
  --no-deps``) and unpacked;
- dm_control's locomotion assets and the dog model (~100 MB, unused by the walker tasks) and
  MuJoCo's ``experimental`` package are left out, so the archive stays under the transfer limit.

On the machine: ``mkdir -p /tmp/site && tar -xJf .gpu/site.tar.xz -C /tmp/site`` and
``export PYTHONPATH=/tmp/site`` (benchmarks/gpu_check.sh does it).
"""

from __future__ import annotations

import argparse
import importlib.metadata as metadata
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from pathlib import Path

ROOTS = ("dvc", "dm-control", "mujoco", "rliable", "h5py", "pandas", "matplotlib", "scipy", "tqdm", "pyyaml")
# Preinstalled on the lent GPU machines ('cuda' image, as read on 2026-11-17; /work/.library/device/KINDS.md).
IMAGE = set("""absl-py accelerate aiofiles aiohappyeyeballs aiohttp aiosignal annotated-doc anyio attrs botorch build
certifi charset-normalizer chex click cloudpickle cmake colorama contourpy coverage cuda-bindings cuda-core
cuda-pathfinder cuda-toolkit cupy-cuda13x cycler cython diffrax e3nn einops equinox etils execnet filelock
flatbuffers flax fonttools formulaic frozenlist fsspec gpytorch grpcio h11 h5py hf-xet httpcore httpx huggingface-hub
humanize hypothesis idna imageio iniconfig interface-meta jax jax-cuda13-pjrt jax-cuda13-plugin jaxlib jaxtyping
jinja2 joblib kiwisolver lazy-loader lightning lightning-utilities linear-operator lineax llvmlite lxml markdown
markdown-it-py markupsafe matplotlib mdurl meson ml-dtypes mpi4py mpmath msgpack multidict multipledispatch
mypy-extensions nanobind narwhals networkx ninja numba numba-cuda numpy numpyro onnx onnx-ir onnxruntime onnxscript
opencv-python-headless optax opt-einsum opt-einsum-fx optimistix orbax-checkpoint packaging pandas pathspec patsy
peft pillow pip pluggy portalocker prometheus-client propcache protobuf psutil pyarrow pybind11 py-cpuinfo pygments
pyparsing pyproject-hooks pyre-extensions pytest pytest-benchmark pytest-cov pytest-mock pytest-timeout
pytest-xdist python-dateutil pytorch-lightning pyyaml regex requests rich sacrebleu safetensors scikit-build-core
scikit-image scikit-learn scipy seaborn sentencepiece sentence-transformers setuptools shellingham simplejson six
sortedcontainers statsmodels sympy tabulate tensorboard tensorboard-data-server tensorstore threadpoolctl tifffile
tiktoken timm tokenizers toolz torch torchaudio torchdiffeq torch-geometric torchmetrics torchvision tqdm
transformers treescope triton typer typing-extensions typing-inspect urllib3 uvloop wadler-lindig werkzeug wheel
wrapt xarray xxhash yarl zipp""".split())
LEFT_OUT = ("dm_control/locomotion", "dm_control/suite/dog_assets", "mujoco/experimental", "dm_control/blender")
PLATFORMS = ("manylinux_2_17_x86_64", "manylinux2014_x86_64", "manylinux_2_24_x86_64", "manylinux_2_27_x86_64",
             "manylinux_2_28_x86_64", "manylinux_2_31_x86_64", "manylinux_2_34_x86_64", "manylinux_2_35_x86_64")


def normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def closure(roots: tuple[str, ...]) -> dict[str, metadata.Distribution]:
    """Every installed distribution the roots need (extras left out)."""
    found: dict[str, metadata.Distribution] = {}
    stack = list(roots)
    while stack:
        name = normalise(stack.pop())
        if name in found:
            continue
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            continue  # a requirement for another platform or Python version
        found[name] = dist
        stack += [re.split(r"[ ;<>=!~\[(]", req, maxsplit=1)[0] for req in dist.requires or []
                  if "extra ==" not in req]
    return found


def compiled(dist: metadata.Distribution) -> bool:
    return any(str(f).endswith(".so") or ".so." in str(f) for f in dist.files or [])


def keep(path: str) -> bool:
    return "__pycache__" not in path and not any(path.startswith(prefix) for prefix in LEFT_OUT)


def download(dist: metadata.Distribution, python: str, into: Path) -> Path:
    command = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:",
               "--python-version", python, "--implementation", "cp", "-d", str(into),
               *[arg for p in PLATFORMS for arg in ("--platform", p)], f"{dist.metadata['Name']}=={dist.version}"]
    before = set(into.iterdir())
    subprocess.run(command, check=True)
    (wheel,) = set(into.iterdir()) - before
    return wheel


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=".gpu/site.tar.xz")
    parser.add_argument("--python", default="3.12", help="the GPU machine's Python version")
    args = parser.parse_args()
    dists = {name: d for name, d in closure(ROOTS).items() if name not in IMAGE}
    with tempfile.TemporaryDirectory() as tmp:
        site, wheels = Path(tmp) / "site", Path(tmp) / "wheels"
        site.mkdir()
        wheels.mkdir()
        for name, dist in sorted(dists.items()):
            if compiled(dist):
                with zipfile.ZipFile(download(dist, args.python, wheels)) as wheel:
                    for member in wheel.namelist():
                        if keep(member):
                            wheel.extract(member, site)
            else:
                for f in dist.files or []:
                    source = Path(dist.locate_file(f))
                    if keep(str(f)) and source.is_file() and not str(f).startswith(".."):
                        (site / f).parent.mkdir(parents=True, exist_ok=True)
                        shutil.copy2(source, site / f)
            print(f"{name}=={dist.version}{' (wheel)' if compiled(dist) else ''}")
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        with tarfile.open(out, "w:xz") as archive:
            archive.add(site, arcname=".")
    print(f"{out}: {len(dists)} distributions, {out.stat().st_size / 2**20:.1f} MiB")


if __name__ == "__main__":
    main()
