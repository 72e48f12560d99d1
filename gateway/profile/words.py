"""The status words a drive answers, decoded for its series: one decoder per word.

| word | decoder | what differs by series |
|---|---|---|
| 2100H state word 1 | `state_word_1` | nothing: 1-6 as every manual lists them |
| 2101H state word 2 | `state_word_2` | bit 0's polarity (`InvtProfile.ready_bit_*`) |
| 2102H, 5000H fault code | `fault` | the fault table (`InvtProfile.faults`) |
| 2103H, 3016H identification | `identification` | nothing: the code names the series |

Every surface asks here: the telemetry (MQTT state, the keys Home Assistant discovery points at,
the console's drive page and API, the fault events) takes the fields, and `invt-gateway read`,
`scan`, the console's traffic monitor and parameter pages print the `show_*` words, each made
from the same decoded value, so no two of them can disagree about a drive.

Without a profile (a `read` of a drive that doesn't say its series) the series-free parts are
decoded and the rest says so: a GD300 and a GD300-LIFT both answer 010AH and read bit 0 the
opposite way, and a fault code is named from the widest table (the GD350 family's).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from gateway.profile.faults import GD350_FAULTS, NO_FAULT, FaultTable
from gateway.profile.invt_codes import describe_identification
from gateway.profile.states import StateWord2, decode_state_word_1, decode_state_word_2


@runtime_checkable
class Series(Protocol):
    """What these decoders read of an INVT series (`invt.InvtProfile`): typed here rather than
    importing the profile, which imports its decoders."""

    @property
    def ready_bit_set_means_ready(self) -> bool: ...

    @property
    def faults(self) -> FaultTable: ...


def state_word_1(raw: int) -> str:
    """2100H: "running_forward", "stopped", "fault", ...; "unknown_<n>" beyond 1-6."""
    return decode_state_word_1(raw)


def state_word_2(profile: Series | None, raw: int) -> StateWord2:
    """2101H with the series' bit-0 polarity; `ready` is None when the series is not known."""
    polarity = None if profile is None else profile.ready_bit_set_means_ready
    return decode_state_word_2(raw, polarity)


@dataclass(frozen=True)
class Fault:
    """A fault code as the drive's own series names it."""

    code: int
    name: str
    """The keypad's short code ("OH2"), "none" for 0, the number for a code without one."""
    description: str
    """ "OH2: inverter module overheat": the one line to print (the short code is in it)."""


def fault_table(profile: Series | None) -> FaultTable:
    return GD350_FAULTS if profile is None else profile.faults


def fault(profile: Series | None, code: int) -> Fault:
    """2102H, 5000H, P07.27-P07.32: a code outside the series' table is "unknown fault N"."""
    table = fault_table(profile)
    name = "none" if code == NO_FAULT else table.short_code(code)
    return Fault(code, name, table.describe(code))


def identification(raw: int) -> str:
    """2103H: "GD350", "GD300 or GD300-LIFT", "GD30 (01F0H unconfirmed)"."""
    return describe_identification(raw)


# -- the words each decoder's answer is printed as --------------------------------------------


def show_state_word_1(raw: int) -> str:
    """ "3 (stopped)"."""
    return f"{raw} ({state_word_1(raw)})"


def show_state_word_2(profile: Series | None, raw: int) -> str:
    """ "0041H (ready, command source communication)"."""
    state = state_word_2(profile, raw)
    if state.ready is None:
        ready = f"bit 0 = {raw & 1}: ready or not depends on the series"
    else:
        ready = "ready" if state.ready else "not ready"
    return f"{raw:04X}H ({ready}, command source {state.command_source})"


def show_fault(profile: Series | None, raw: int) -> str:
    """ "16 (OH2: inverter module overheat)", "0 (none)", "40 (unknown fault 40)"."""
    return f"{raw} ({fault(profile, raw).description})"


def show_identification(raw: int) -> str:
    """ "01A0H (GD350)"."""
    return f"{raw:04X}H ({identification(raw)})"
