"""Everything the gateway knows about drives, as data: no I/O.

- `protocol`: the `DriveProfile` protocol, what the gateway asks of any model (identification,
  register words and their decoders, commands, faults, parameters).
- `models`: the registry of model names (`get_profile`, `PROFILES`), every maker's.
- `generic`: a Modbus device the gateway only carries.
- `points`: the point resolver (`P00.11`, `2100H`, `output_frequency`) and `Point`.

Other Modbus devices (meters, transmitters, remote I/O), described by device files:

- `device_files`: a device file (`data/devices/*.yaml`, or a site's `file:PATH`), checked whole
  at load, read into its `points_device.DeviceProfile`.
- `point_types`: typed points (u16...f64, strings, bits, enumerations, coils) in each word and
  byte order, and where each table's words are kept (`word_key`).
- `read_plan`: the reads planned from the points; `report_by_exception`: when a reading is news;
  `limit_alarms`: high and low limits with hysteresis and delay.

INVT, one implementation of the protocol:

- `addressing`: Pxx.yy ↔ register, RAM-only addresses, register spellings ("2100H", "0x2100").
- `registers`: the communication registers (2000H..., 2100H..., 3000H...) and the telemetry keys.
- `parameters`: a Pxx.yy parameter's description (decimals, range, default, marks, words), and
  the common table of 25 codes every series shares.
- `parameter_tables`: each series' whole table, loaded from `data/` (CSV rows, sources per group).
- `states`: control word commands, state words 1 and 2 (the bit-level codecs).
- `words`: one decoder per status word (2100H, 2101H, fault codes, 2103H) for a drive's series:
  what every surface (telemetry, `read`, `scan`, the console, the events) shows.
- `faults`: fault codes → short code and description, one table per series.
- `exception_codes`: each maker's words for the exception codes (INVT's, the Modbus standard's),
  one table each, named by the profile (`DriveProfile.exceptions`).
- `invt`: model identification codes and the `InvtProfile` of each series.
"""

from gateway.profile.addressing import (
    format_parameter,
    format_register,
    is_parameter_register,
    is_ram_address,
    parse_parameter,
    parse_register,
    ram_address,
)
from gateway.profile.exception_codes import INVT_EXCEPTIONS, STANDARD_EXCEPTIONS, ExceptionNames
from gateway.profile.faults import FAULTS, FaultTable, describe_fault, fault_short_code
from gateway.profile.generic import GenericProfile
from gateway.profile.invt import (
    IDENTIFICATION_CODES,
    InvtProfile,
    describe_identification,
    model_from_identification,
    profiles_for_identification,
)
from gateway.profile.models import PROFILES, SCAN_QUESTIONS, get_profile
from gateway.profile.parameters import (
    PARAMETERS,
    Parameter,
    parameter,
    parameter_at,
    parameter_decimals,
    scale_parameter,
    unscale_parameter,
)
from gateway.profile.points import Point, resolve
from gateway.profile.protocol import DriveProfile, Identified, PollGroup, Question, RegisterWrite
from gateway.profile.registers import (
    COMMUNICATION_REGISTERS,
    RUNNING_VALUES,
    Register,
    RunningValue,
    decode_running_values,
    register_at,
    register_by_name,
)
from gateway.profile.states import (
    CONTROL_COMMANDS,
    CommandSource,
    ControlCommand,
    RunState,
    StateWord2,
    control_command,
    decode_state_word_1,
    decode_state_word_2,
    encode_state_word_2,
)

__all__ = [
    "COMMUNICATION_REGISTERS",
    "CONTROL_COMMANDS",
    "FAULTS",
    "IDENTIFICATION_CODES",
    "INVT_EXCEPTIONS",
    "PARAMETERS",
    "PROFILES",
    "RUNNING_VALUES",
    "SCAN_QUESTIONS",
    "STANDARD_EXCEPTIONS",
    "CommandSource",
    "ControlCommand",
    "DriveProfile",
    "ExceptionNames",
    "FaultTable",
    "GenericProfile",
    "Identified",
    "InvtProfile",
    "Parameter",
    "Point",
    "PollGroup",
    "Question",
    "Register",
    "RegisterWrite",
    "RunState",
    "RunningValue",
    "StateWord2",
    "control_command",
    "decode_running_values",
    "decode_state_word_1",
    "decode_state_word_2",
    "describe_fault",
    "describe_identification",
    "encode_state_word_2",
    "fault_short_code",
    "format_parameter",
    "format_register",
    "get_profile",
    "is_parameter_register",
    "is_ram_address",
    "model_from_identification",
    "parameter",
    "parameter_at",
    "parameter_decimals",
    "parse_parameter",
    "parse_register",
    "profiles_for_identification",
    "ram_address",
    "register_at",
    "register_by_name",
    "resolve",
    "scale_parameter",
    "unscale_parameter",
]
