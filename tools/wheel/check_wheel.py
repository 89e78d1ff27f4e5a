"""Install the newest tdtp wheel of a directory into a fresh venv with no C compiler on PATH and check
that the compiled core and the C datagram layer load, and that the docstrings came along.

    python tools/wheel/check_wheel.py dist      # `make wheel-check`, which CI runs after `make test`

The venv's PATH holds only the venv's own ``bin`` (and ``CC``/``CXX`` point to ``false``), so nothing
could be compiled during the install: what runs is what the wheel carries. The dependencies come from
the package index as for any user. Exit status 0 when all holds, 1 otherwise, saying what failed.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import venv
from pathlib import Path

CHECK = """
import json, tdtp
from tdtp.aio.datagram import datagram_build_info
info, layer = tdtp.build_info(), datagram_build_info()
print(json.dumps({
    "core": info.describe(), "core_compiled": info.compiled,
    "datagram_layer": layer.describe(), "datagram_compiled": layer.compiled,
    "send_control_doc": bool(tdtp.Endpoint.send_control.__doc__),
    "location": tdtp.__file__,
}))
"""


def main(directory: str) -> int:
    wheels = sorted(Path(directory).glob("tdtp-*manylinux*.whl"), key=lambda p: p.stat().st_mtime)
    if not wheels:
        print(
            f"check_wheel: no manylinux tdtp wheel in {directory}; run `make wheel`",
            file=sys.stderr,
        )
        return 1
    wheel = wheels[-1].resolve()
    with tempfile.TemporaryDirectory(prefix="tdtp-wheel-") as tmp:
        env_dir = Path(tmp) / "venv"
        venv.create(env_dir, with_pip=True)
        bin_dir = env_dir / "bin"
        env = {
            "PATH": str(bin_dir),
            "CC": "false",
            "CXX": "false",
            "HOME": os.environ.get("HOME", tmp),  # the user's pip configuration, if any
            "PIP_DISABLE_PIP_VERSION_CHECK": "1",
        }
        for name in (
            "PIP_INDEX_URL",
            "PIP_EXTRA_INDEX_URL",
            "PIP_FIND_LINKS",
            "PIP_CERT",
            "PIP_CONFIG_FILE",
        ):
            if name in os.environ:
                env[name] = os.environ[name]
        steps = (
            (f"installing {wheel.name}", ["-m", "pip", "install", "--quiet", str(wheel)]),
            ("importing tdtp", ["-c", CHECK]),
        )
        for what, args in steps:
            run = subprocess.run(
                [str(bin_dir / "python"), *args],
                env=env,
                cwd=tmp,
                capture_output=True,
                text=True,
                check=False,
            )
            if run.returncode != 0:
                print(f"check_wheel: {what} failed:\n{run.stderr}", file=sys.stderr)
                return 1
        print(f"{wheel.name}: {run.stdout.strip()}")
        report = run.stdout
        failed = [
            what
            for what in ("core_compiled", "datagram_compiled", "send_control_doc")
            if f'"{what}": true' not in report
        ]
        if str(env_dir) not in report:
            failed.append("tdtp imported from outside the venv")
        if failed:
            print(f"check_wheel: {', '.join(failed)}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else "dist"))
