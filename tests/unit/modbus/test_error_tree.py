"""One exception tree (`gateway.errors`) and one name per Modbus exception code."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import gateway
from gateway import errors
from gateway.errors import ExceptionCode, GatewayError
from gateway.profile import INVT_EXCEPTIONS
from gateway.profile import exception_codes as invt


def _every_module() -> list[str]:
    modules = pkgutil.walk_packages(gateway.__path__, "gateway.")
    return [m.name for m in modules if not m.name.endswith(".__main__")]  # that one runs the CLI


def test_every_exception_class_of_the_gateway_is_in_the_one_tree() -> None:
    elsewhere = []
    for name in _every_module():
        module = importlib.import_module(name)
        for attribute, value in vars(module).items():
            if (
                inspect.isclass(value)
                and issubclass(value, BaseException)
                and value.__module__ == name
                and name != errors.__name__
            ):
                elsewhere.append(f"{name}.{attribute}")
    assert elsewhere == []
    in_tree = [
        value
        for value in vars(errors).values()
        if inspect.isclass(value) and issubclass(value, BaseException)
    ]
    assert all(issubclass(cls, GatewayError) for cls in in_tree)
    # The module docstring draws the tree: every class is on it.
    assert errors.__doc__ is not None
    assert all(cls.__name__ in errors.__doc__ for cls in in_tree)


def test_exception_codes_have_one_name_each_from_01h_to_0bh() -> None:
    assert [int(code) for code in ExceptionCode] == list(range(0x01, 0x0C))
    assert len({code.name for code in ExceptionCode}) == len(ExceptionCode)


def test_invt_names_are_the_same_codes_with_invt_meanings() -> None:
    assert invt.DATA_FRAME_ERROR is ExceptionCode.SERVER_DEVICE_BUSY
    assert INVT_EXCEPTIONS.name(ExceptionCode.SERVER_DEVICE_BUSY) == "data_frame_error"
    assert INVT_EXCEPTIONS.name(6) == "data_frame_error"
    assert INVT_EXCEPTIONS.describe(invt.PASSWORD_PROTECTION) == (
        "09H password protection: the drive is locked by a password"
    )
    assert INVT_EXCEPTIONS.name(0x0C) == "exception_0c"
