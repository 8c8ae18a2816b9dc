"""Build the tf2_msgs interface package (ros_ws/vendor/tf2_msgs) and install it into a venv.

tf2_msgs (TFMessage for /tf and /tf_static) is not on PyPI, but the venv has everything to
generate it: requirements.lock pins the ROS 2 Jazzy rosidl generators, ament_cmake and its test
modules (ament_cmake_ros finds them even with BUILD_TESTING off), CMake and Ninja. This script
configures, builds and installs the vendored package with the venv as the install prefix, the
layout of the ros-jazzy-* wheels: libraries in .venv/lib (on LD_LIBRARY_PATH through
ros_wheels_bootstrapper), the Python package in site-packages, CMake config in .venv/share.

From the system it needs a C and a C++ compiler (cc/c++ or $CC/$CXX; Debian: build-essential)
and the Python headers of the venv's interpreter (Debian: python3-dev). Missing either, it
prints ONE warning line (details in the log) and exits 1; the nodes then run without TF.

One workaround: the ros-jazzy-* wheels export their `*__rosidl_generator_py` CMake targets with
the wheel builder's Python and NumPy include directories (/opt/python/...), which do not exist
here; CMake refuses such imported targets. A snippet run at the end of configuration (injected
with CMAKE_PROJECT_INCLUDE, so the vendored sources stay as upstream has them) points those
entries at this venv's include directories. Nothing installed by pip is modified.

Usage (the Makefile's venv step runs it; `make tf2_msgs` forces a rebuild):
    .venv/bin/python tools/build_tf2_msgs.py [--venv .venv] [--stamp FILE]
Exit status 0: installed and `from tf2_msgs.msg import TFMessage` works in a fresh process.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SOURCE = REPO / "ros_ws" / "vendor" / "tf2_msgs"
WARNING = "warning: tf2_msgs not built ({reason}); the nodes run without /tf and /tf_static."
HINT = "Needs a C/C++ compiler and the Python headers (Debian: build-essential python3-dev), then `make tf2_msgs`."

#: Runs when the top directory has been read, before generation: CMake checks the include
#: directories of imported targets at generation, so rewriting them here is in time.
FIX_INCLUDES_CMAKE = r"""
function(_softhand_fix_wheel_includes)
  get_property(_targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(_t IN LISTS _targets)
    get_target_property(_dirs ${_t} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT _dirs)
      continue()
    endif()
    set(_new "")
    set(_changed FALSE)
    foreach(_d IN LISTS _dirs)
      if(NOT EXISTS "${_d}" AND _d MATCHES "numpy/(_core/)?include$")
        list(APPEND _new "${SOFTHAND_NUMPY_INCLUDE}")
        set(_changed TRUE)
      elseif(NOT EXISTS "${_d}" AND _d MATCHES "include/python3\\.[0-9]+$")
        list(APPEND _new "${SOFTHAND_PYTHON_INCLUDE}")
        set(_changed TRUE)
      else()
        list(APPEND _new "${_d}")
      endif()
    endforeach()
    if(_changed)
      set_target_properties(${_t} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_new}")
    endif()
  endforeach()
endfunction()
cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _softhand_fix_wheel_includes)
"""


class BuildError(RuntimeError):
    """A step failed; the message is the short reason for the one warning line."""


def find_compiler(env_var: str, default: str) -> str:
    """Path of the compiler named by $CC/$CXX (first word) or `default`; BuildError if absent."""
    name = (os.environ.get(env_var) or default).split()[0]
    path = shutil.which(name)
    if path is None:
        raise BuildError(f"no {'C' if env_var == 'CC' else 'C++'} compiler: {name!r} not found"
                         f"{f' (from ${env_var})' if os.environ.get(env_var) else ''}")
    return path


def python_includes(python: Path) -> tuple[str, str]:
    """(Python include dir, NumPy include dir) of the venv's interpreter; BuildError if no Python.h."""
    code = "import sysconfig, numpy; print(sysconfig.get_paths()['include']); print(numpy.get_include())"
    out = subprocess.run([str(python), "-c", code], capture_output=True, text=True)
    if out.returncode != 0:
        raise BuildError(f"cannot query {python}: {out.stderr.strip().splitlines()[-1:]}")
    py_inc, np_inc = out.stdout.split()
    if not (Path(py_inc) / "Python.h").is_file():
        raise BuildError(f"no Python headers: {py_inc}/Python.h missing")
    return py_inc, np_inc


def build_env(venv: Path) -> dict:
    env = dict(os.environ)
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["AMENT_PREFIX_PATH"] = str(venv)
    env["CMAKE_PREFIX_PATH"] = str(venv)
    env["LD_LIBRARY_PATH"] = os.pathsep.join(p for p in (str(venv / "lib"), env.get("LD_LIBRARY_PATH")) if p)
    return env


def run(cmd, log, env) -> None:
    log.write(f"\n$ {' '.join(map(str, cmd))}\n")
    log.flush()
    proc = subprocess.run([str(c) for c in cmd], stdout=log, stderr=subprocess.STDOUT, env=env)
    if proc.returncode != 0:
        raise BuildError(f"`{Path(str(cmd[0])).name} {cmd[1]}` failed with exit status {proc.returncode}")


def check_import(venv: Path, env) -> None:
    """Import TFMessage in a fresh venv interpreter (the way the nodes will)."""
    code = "from tf2_msgs.msg import TFMessage; TFMessage()"
    proc = subprocess.run([str(venv / "bin" / "python"), "-c", code], capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise BuildError(f"built, but `{code}` fails: {(proc.stderr.strip().splitlines() or ['?'])[-1]}")


def build(venv: Path, source: Path, build_dir: Path, log) -> None:
    cmake, ninja = venv / "bin" / "cmake", venv / "bin" / "ninja"
    for tool in (cmake, ninja):
        if not tool.exists():
            raise BuildError(f"{tool} missing (it is pinned in requirements.lock: run `make venv`)")
    cc, cxx = find_compiler("CC", "cc"), find_compiler("CXX", "c++")
    py_inc, np_inc = python_includes(venv / "bin" / "python")
    build_dir.mkdir(parents=True, exist_ok=True)
    fix = build_dir / "fix_wheel_includes.cmake"
    fix.write_text(FIX_INCLUDES_CMAKE)
    env = build_env(venv)
    # the vendored package's own (ament) environment hooks must not leak in from a sourced ROS
    env.pop("COLCON_PREFIX_PATH", None)
    run([cmake, "-S", source, "-B", build_dir, "-G", "Ninja", f"-DCMAKE_MAKE_PROGRAM={ninja}",
         f"-DCMAKE_C_COMPILER={cc}", f"-DCMAKE_CXX_COMPILER={cxx}",
         f"-DCMAKE_INSTALL_PREFIX={venv}", f"-DCMAKE_PREFIX_PATH={venv}", "-DCMAKE_BUILD_TYPE=Release",
         "-DBUILD_TESTING=OFF", f"-DPython3_EXECUTABLE={venv / 'bin' / 'python'}",
         f"-DSOFTHAND_PYTHON_INCLUDE={py_inc}", f"-DSOFTHAND_NUMPY_INCLUDE={np_inc}",
         f"-DCMAKE_PROJECT_INCLUDE={fix}", "-Wno-dev", "-Wno-deprecated"], log, env)
    run([cmake, "--build", build_dir, "--parallel", str(min(os.cpu_count() or 1, 4))], log, env)
    run([cmake, "--install", build_dir], log, env)
    check_import(venv, env)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--venv", type=Path, default=Path(sys.prefix), help="venv to install into (default: this one)")
    ap.add_argument("--source", type=Path, default=SOURCE, help="tf2_msgs package sources")
    ap.add_argument("--build-dir", type=Path, default=None, help="default: VENV/build/tf2_msgs")
    ap.add_argument("--stamp", type=Path, default=None,
                    help="file written in both outcomes ('built ...' or 'not built: reason'), for make")
    args = ap.parse_args(argv)
    venv = args.venv.resolve()
    build_dir = (args.build_dir or venv / "build" / "tf2_msgs").resolve()
    build_dir.mkdir(parents=True, exist_ok=True)
    log_path = build_dir.parent / "tf2_msgs-build.log"
    t0 = time.monotonic()
    with open(log_path, "w") as log:
        try:
            build(venv, args.source.resolve(), build_dir, log)
            status, code = f"built in {time.monotonic() - t0:.0f} s into {venv}", 0
            print(f"tf2_msgs {status} (log: {log_path})", flush=True)
        except BuildError as exc:
            log.write(f"\nFAILED: {exc}\n")
            status, code = f"not built: {exc}", 1
            print(f"{WARNING.format(reason=exc)} {HINT} Log: {log_path}", file=sys.stderr, flush=True)
    if args.stamp is not None:
        args.stamp.write_text(f"tf2_msgs {status}\n")
    return code


if __name__ == "__main__":
    sys.exit(main())
