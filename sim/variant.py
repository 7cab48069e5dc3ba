"""Choose and activate the Mitsuba variant that evfuse renders with.

Order of preference: ``cuda_ad_rgb`` when a GPU works, ``llvm_ad_rgb`` when a working LLVM >= 16
is found, else ``scalar_rgb`` (much slower). ``EVFUSE_VARIANT`` or an explicit ``variant`` argument
(the command line's ``--variant``) forces one.

Dr.Jit reads ``DRJIT_LIBLLVM_PATH`` once, at the first ``import drjit``, and an LLVM that is too old
(15 and below for Dr.Jit 1.5) aborts the whole process at the first render. So every candidate is
tried in a child process first (a one-pixel render), and the result is cached per machine in
``$XDG_CACHE_HOME/evfuse/variants.json`` (keyed by the library path, its size and modification time
and the Mitsuba version), so that only the first run on a machine pays for the probe.
"""

from __future__ import annotations

import ctypes.util
import glob
import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

__all__ = ["KNOWN_VARIANTS", "LlvmLibrary", "active_variant", "find_llvm_libraries", "use_variant"]

KNOWN_VARIANTS = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")
MIN_LLVM_VERSION = 16
VARIANT_TERM = "variant="
"""How a refusal names the forced variant's parameter (:func:`use_variant`'s ``variant``): the
``{variant}`` of a :class:`~sim.validation.ParameterError`, which a front end names its way."""

_LLVM_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/lib/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/usr/local/opt/llvm/lib/libLLVM*.dylib",
    "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib",
)

# A one-pixel scene rendered by the probe: enough to make Dr.Jit compile and run a kernel.
_PROBE = """
import mitsuba as mi
mi.set_variant({variant!r})
scene = mi.load_dict({{
    "type": "scene",
    "integrator": {{"type": "direct"}},
    "sensor": {{"type": "perspective", "film": {{"type": "hdrfilm", "width": 2, "height": 2}}}},
    "shape": {{"type": "sphere", "center": [0, 0, 3]}},
    "light": {{"type": "point", "position": [0, 0, 0]}},
}})
image = mi.render(scene, spp=1)
import numpy as np\nprint(float(np.asarray(image).sum()))
"""

_active: str | None = None


@dataclass(frozen=True)
class LlvmLibrary:
    """A shared LLVM library found on this machine.

    Attributes
    ----------
    path : str
        Absolute path of the library file.
    version : int or None
        Major version read from the file or folder name, None when the name does not say.
    """

    path: str
    version: int | None


def _llvm_version(path: str) -> int | None:
    name = os.path.basename(path)
    for pattern in (r"libLLVM-(\d+)", r"libLLVM\.so\.(\d+)", r"libLLVM\.(\d+)\.dylib"):
        match = re.search(pattern, name)
        if match:
            return int(match.group(1))
    match = re.search(r"llvm-(\d+)", path)
    return int(match.group(1)) if match else None


def find_llvm_libraries() -> list[LlvmLibrary]:
    """List the LLVM shared libraries on this machine, newest first.

    ``DRJIT_LIBLLVM_PATH``, when set, comes first whatever its version. Libraries whose name says
    they are older than LLVM 16 are left out: Dr.Jit 1.5 aborts the process with them.

    Returns
    -------
    list of LlvmLibrary
        One entry per distinct file (symbolic links resolved), newest version first, unknown
        versions last.
    """
    found: dict[str, LlvmLibrary] = {}
    for pattern in _LLVM_GLOBS:
        for path in glob.glob(pattern):
            real = os.path.realpath(path)
            version = _llvm_version(path) or _llvm_version(real)
            if version is not None and version < MIN_LLVM_VERSION:
                continue
            if real not in found or found[real].version is None:
                found[real] = LlvmLibrary(path, version)
    libraries = sorted(found.values(), key=lambda lib: -(lib.version or 0))
    forced = os.environ.get("DRJIT_LIBLLVM_PATH")
    if forced:
        libraries = [LlvmLibrary(forced, _llvm_version(forced))] + [
            lib for lib in libraries if os.path.realpath(lib.path) != os.path.realpath(forced)
        ]
    return libraries


def _cache_path() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "evfuse" / "variants.json"


def _cache_key(variant: str, library: str | None) -> str:
    stamp = ""
    if library and os.path.exists(library):
        stat = os.stat(os.path.realpath(library))
        stamp = f"{stat.st_size}:{int(stat.st_mtime)}"
    try:
        version = metadata.version("mitsuba")
    except metadata.PackageNotFoundError:
        version = "?"
    return f"{variant}|{library}|{stamp}|mitsuba {version}|{sys.executable}"


def _probe(variant: str, library: str | None) -> bool:
    """Render one tiny image with ``variant`` in a child process; True when it worked."""
    cache_file = _cache_path()
    key = _cache_key(variant, library)
    try:
        cache = json.loads(cache_file.read_text())
    except (OSError, ValueError):
        cache = {}
    if key in cache:
        return bool(cache[key])
    env = dict(os.environ)
    if library:
        env["DRJIT_LIBLLVM_PATH"] = library
    try:
        done = subprocess.run(
            [sys.executable, "-c", _PROBE.format(variant=variant)],
            env=env, capture_output=True, timeout=180, check=False,
        )
        works = done.returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        works = False
    cache[key] = works
    try:
        cache_file.parent.mkdir(parents=True, exist_ok=True)
        tmp = cache_file.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps(cache, indent=1, sort_keys=True))
        tmp.replace(cache_file)
    except OSError:
        pass
    return works


def _cuda_driver_present() -> bool:
    return ctypes.util.find_library("cuda") is not None or os.path.exists("/dev/nvidiactl")


def _say(message: str) -> None:
    print(f"evfuse: {message}", file=sys.stderr, flush=True)


_ANSI_ESCAPE = re.compile(r"\x1b\[[0-9;]*m")
_appender = None     # the Mitsuba appender installed by _route_mitsuba_log, kept alive here


def _route_mitsuba_log(mi) -> None:
    """Mitsuba's log as evfuse's own one-line messages on standard error.

    Mitsuba's stream appender writes warnings in colour, with a date and a thread name, straight
    to the process's standard error; each one comes out instead as ``evfuse: Mitsuba warning:
    [Class] text`` (one line, no escape codes), and Mitsuba's progress bars are dropped (evfuse
    draws its own).
    """
    global _appender

    class OneLineAppender(mi.Appender):
        def append(self, level, text):
            kind = "error" if level == mi.LogLevel.Error else "warning"
            _say(f"Mitsuba {kind}: {' '.join(_ANSI_ESCAPE.sub('', str(text)).split())}")

        def log_progress(self, progress, name, formatted, eta, ptr=None):
            pass

    logger = mi.logger() if hasattr(mi, "logger") else mi.Thread.thread().logger()
    formatter = logger.formatter()
    for setting in ("set_has_date", "set_has_thread", "set_has_log_level"):
        getattr(formatter, setting)(False)
    logger.clear_appenders()
    _appender = OneLineAppender()
    logger.add_appender(_appender)


def _choose(forced: str | None) -> tuple[str, str | None, str]:
    """Return (variant, llvm library path or None, why)."""
    # Imported here: ``python sim/variant.py --find-llvm`` (make llvm) runs this file alone, with
    # the standard library only.
    from sim.validation import ParameterError

    libraries = find_llvm_libraries()
    if forced:
        if forced not in KNOWN_VARIANTS:
            raise ParameterError(
                f"unknown Mitsuba variant {ParameterError.literal(repr(forced))} (from {{variant}} "
                f"or EVFUSE_VARIANT); expected one of {', '.join(KNOWN_VARIANTS)}",
                variant=VARIANT_TERM)
        if forced == "llvm_ad_rgb":
            working = next((lib for lib in libraries if _probe(forced, lib.path)), None)
            if working is None:
                raise ValueError(
                    "llvm_ad_rgb was asked for, but no working LLVM >= 16 was found "
                    "(install Debian's libllvm19, e.g. `make setup` as root, or set "
                    "DRJIT_LIBLLVM_PATH)"
                )
            return forced, working.path, "forced"
        if forced == "cuda_ad_rgb" and not (
                _cuda_driver_present()
                and _probe(forced, libraries[0].path if libraries else None)):
            instead = next(("llvm_ad_rgb" for lib in libraries
                            if _probe("llvm_ad_rgb", lib.path)), "scalar_rgb")
            raise ParameterError(f"cuda_ad_rgb was asked for (from {{variant}} or "
                                 f"EVFUSE_VARIANT), but no CUDA device works here; use {instead}",
                                 variant=VARIANT_TERM)
        return forced, libraries[0].path if libraries else None, "forced"
    if _cuda_driver_present() and _probe("cuda_ad_rgb", libraries[0].path if libraries else None):
        return "cuda_ad_rgb", libraries[0].path if libraries else None, "a GPU works"
    for lib in libraries:
        if _probe("llvm_ad_rgb", lib.path):
            version = f"LLVM {lib.version}" if lib.version else "LLVM"
            return "llvm_ad_rgb", lib.path, f"{version} at {lib.path}"
    tried = ", ".join(lib.path for lib in libraries) or "none found"
    return "scalar_rgb", None, (
        f"no working LLVM >= {MIN_LLVM_VERSION} (tried: {tried}); scalar_rgb renders one ray at a "
        "time and is far slower. Install Debian's libllvm19 (`make setup` does, as root) or set "
        "DRJIT_LIBLLVM_PATH"
    )


def use_variant(variant: str | None = None) -> str:
    """Activate the Mitsuba variant evfuse renders with, choosing it on the first call.

    Parameters
    ----------
    variant : str, optional
        Force a variant (one of ``KNOWN_VARIANTS``). Default: ``EVFUSE_VARIANT`` if set, else the
        fastest variant that works on this machine.

    Returns
    -------
    str
        The active variant. The choice is announced once per process on standard error.

    Raises
    ------
    ValueError
        For an unknown variant, a forced ``llvm_ad_rgb`` with no working LLVM, a forced
        ``cuda_ad_rgb`` with no working CUDA device (probed, as ``llvm_ad_rgb``, in a child
        process; the message names the variant to use instead; these two are
        :class:`~sim.validation.ParameterError` naming the parameter ``variant``), or a second call
        that asks for a different variant than the one already active (Dr.Jit cannot reload).
    """
    global _active
    forced = variant or os.environ.get("EVFUSE_VARIANT") or None
    if _active is not None:
        if forced and forced != _active:
            raise ValueError(
                f"Mitsuba variant {_active} is already active in this process; cannot switch "
                f"to {forced}"
            )
        return _active
    chosen, library, why = _choose(forced)
    if library and "drjit" not in sys.modules:
        os.environ["DRJIT_LIBLLVM_PATH"] = library
    import mitsuba as mi

    mi.set_variant(chosen)
    _route_mitsuba_log(mi)
    _active = chosen
    _say(f"rendering with Mitsuba variant {chosen} ({why})")
    return chosen


def active_variant() -> str | None:
    """The variant activated by :func:`use_variant` in this process, or None."""
    return _active


def _main(argv: list[str]) -> int:
    """``python sim/variant.py --find-llvm``: print the LLVM library evfuse would try first
    (:func:`find_llvm_libraries`) and exit 0, or exit 1 when there is none. The Makefile's
    ``llvm`` target asks this, so that it and evfuse agree on what is installed; it needs only
    the standard library (it runs before the virtual environment exists)."""
    if argv != ["--find-llvm"]:
        print("usage: python sim/variant.py --find-llvm", file=sys.stderr)
        return 2
    libraries = find_llvm_libraries()
    if not libraries:
        return 1
    first = libraries[0]
    print(f"LLVM {first.version} at {first.path}" if first.version else first.path)
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
