"""Build the kdfaces Blender extension zip (Blender 4.2+ extension format, Linux x86-64, Blender's Python 3.11).

The zip is what ``blender --command extension build`` makes of ``kdfaces/blender/``: ``blender_manifest.toml`` and
the extension's modules at the zip root, and ``wheels/`` holding

- the kdfaces wheel of this source tree (``pip wheel --no-deps .``), and
- the Linux x86-64 cp311 wheels of the runtime dependencies the KD/IKD core needs inside Blender
  (:data:`DEPENDENCIES`, pinned to the versions installed here, so Blender runs what the tests ran). numpy is not
  bundled: Blender ships it. The rest of kdfaces' dependencies (renders, FEM, USD writer, …) are not needed for
  KD on the timeline, IKD or PC2 bakes, and are imported only by the features that use them.

The manifest's ``version`` comes from pyproject.toml and ``wheels`` lists the bundled files. Dependency wheels are
downloaded once (``pip download --only-binary=:all: --platform manylinux_2_28_x86_64 --platform
manylinux2014_x86_64 --python-version 3.11``) into a cache (``--cache``, default ``$KDFACES_CACHE/blender-wheels``),
so a second build only rebuilds the kdfaces wheel and the zip.

Run:  python scripts/build_blender_extension.py [--out dist] [--cache DIR]
      → dist/kdfaces-<version>-linux_x64.zip
Install: Blender › Edit › Preferences › Get Extensions › ⌄ › Install from Disk…, or
      blender --command extension install-file -r user_default -e dist/kdfaces-<version>-linux_x64.zip
Python: ``build_extension(out, cache=None)`` returns the zip's path.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "kdfaces" / "blender"

#: The distributions the extension's KD, IKD and bakes need inside Blender besides numpy (Blender's own): Warp (the
#: face dynamics' kernels), SciPy (sparse clusters, IKD's linear algebra), tomlkit and pydantic with its own
#: dependencies (shot files, which the bake writes and runs), threadpoolctl (one BLAS thread during KD). Found by
#: importing kdfaces.kd, .window, .dynamics, .ikd, .shots.run, .io.export and .io.pointcache in a clean Python 3.11
#: with only these and numpy 1.26. Pinned to the versions installed in this environment.
DEPENDENCIES = ("warp-lang", "scipy", "tomlkit", "pydantic", "pydantic-core", "annotated-types",
                "typing-extensions", "typing-inspection", "threadpoolctl")
#: Blender 4.2+ runs on glibc 2.28+ (manylinux_2_28); older manylinux2014 wheels are accepted too.
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux2014_x86_64")
PYTHON_VERSION = "3.11"


class BuildError(RuntimeError):
    """The extension could not be built (one line naming what failed)."""


def _normal(name: str) -> str:
    return re.sub(r"[-_.]+", "_", name).lower()


def pinned_dependencies() -> list[str]:
    """``name==version`` of each of :data:`DEPENDENCIES` as installed here (an absent one is a BuildError)."""
    out = []
    for name in DEPENDENCIES:
        try:
            out.append(f"{name}=={metadata.version(name)}")
        except metadata.PackageNotFoundError:
            raise BuildError(f"{name} is not installed here; install kdfaces' dependencies first (pip install -e .)"
                             ) from None
    return out


def _cached_wheel(cache: Path, requirement: str) -> Path | None:
    name, version = requirement.split("==")
    for p in sorted(cache.glob("*.whl")):
        parts = p.name.split("-")
        if _normal(parts[0]) == _normal(name) and parts[1] == version:
            return p
    return None


def dependency_wheels(cache: Path) -> list[Path]:
    """The Linux x86-64 cp311 wheels of :func:`pinned_dependencies`, from ``cache`` or downloaded into it."""
    cache.mkdir(parents=True, exist_ok=True)
    reqs = pinned_dependencies()
    missing = [r for r in reqs if _cached_wheel(cache, r) is None]
    if missing:
        cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "--python-version",
               PYTHON_VERSION, "--implementation", "cp", "--abi", "cp311", "--abi", "abi3", "--abi", "none",
               "-d", str(cache)]
        for plat in PLATFORMS:
            cmd += ["--platform", plat]
        r = subprocess.run(cmd + missing, capture_output=True, text=True)
        if r.returncode:
            last = (r.stderr.strip() or r.stdout.strip()).splitlines()[-1:] or ["no output"]
            raise BuildError(f"pip download of {', '.join(missing)} failed: {last[0]}")
    wheels = [_cached_wheel(cache, r) for r in reqs]
    lost = [r for r, w in zip(reqs, wheels) if w is None]
    if lost:
        raise BuildError(f"pip download left no wheel for {', '.join(lost)} in {cache}")
    return wheels


def kdfaces_wheel(tmp: Path) -> Path:
    """``pip wheel --no-deps .`` of this source tree into ``tmp``."""
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                        str(tmp), str(ROOT)], capture_output=True, text=True)
    found = sorted(tmp.glob("kdfaces-*.whl"))
    if r.returncode or not found:
        last = (r.stderr.strip() or r.stdout.strip()).splitlines()[-1:] or ["no wheel written"]
        raise BuildError(f"pip wheel of {ROOT} failed: {last[0]}")
    return found[0]


def manifest_text(version: str, wheels: list[str]) -> str:
    """The source manifest with ``version`` and ``wheels`` (paths relative to the zip root) filled in."""
    text = (SOURCE / "blender_manifest.toml").read_text()
    listed = ", ".join(f'"./wheels/{w}"' for w in wheels)
    text, n1 = re.subn(r'(?m)^version = ".*"$', f'version = "{version}"', text)
    text, n2 = re.subn(r"(?m)^wheels = \[.*\]$", f"wheels = [{listed}]", text)
    if n1 != 1 or n2 != 1:
        raise BuildError(f"{SOURCE / 'blender_manifest.toml'}: expected one 'version = ' and one 'wheels = [...]' line")
    tomllib.loads(text)  # still valid TOML
    return text


def build_extension(out, cache=None) -> Path:
    """Build the extension zip into folder ``out``; returns its path (written next to it, then renamed)."""
    out = Path(out)
    if cache is None:
        from kdfaces.defaults import user_cache_dir

        cache = user_cache_dir() / "blender-wheels"
    cache = Path(cache)
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    deps = dependency_wheels(cache)
    out.mkdir(parents=True, exist_ok=True)
    target = out / f"kdfaces-{version}-linux_x64.zip"
    with tempfile.TemporaryDirectory(prefix="kdfaces-ext-") as tmp:
        own = kdfaces_wheel(Path(tmp))
        wheels = [own, *deps]
        fd, partial = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".partial", dir=out)
        os.close(fd)
        try:
            with zipfile.ZipFile(partial, "w") as z:
                z.writestr("blender_manifest.toml", manifest_text(version, [w.name for w in wheels]),
                           compress_type=zipfile.ZIP_DEFLATED)
                for p in sorted(SOURCE.glob("*.py")):
                    z.write(p, p.name, compress_type=zipfile.ZIP_DEFLATED)
                for w in wheels:  # wheels are zips already
                    z.write(w, f"wheels/{w.name}", compress_type=zipfile.ZIP_STORED)
            os.chmod(partial, 0o644)
            os.replace(partial, target)
        finally:
            if os.path.exists(partial):
                os.unlink(partial)
    return target


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "dist"), help="folder for the zip (default dist/)")
    ap.add_argument("--cache", default=None, help="dependency wheel cache (default $KDFACES_CACHE/blender-wheels)")
    args = ap.parse_args(argv)
    try:
        path = build_extension(args.out, args.cache)
    except BuildError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {path} ({path.stat().st_size / 2**20:.0f} MiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
