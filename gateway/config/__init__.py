"""The configuration: one YAML file, validated completely at load, including cross-field checks.

The key names are a public interface (users' files depend on them): add, never rename. A file that
doesn't validate raises ConfigError naming each key path and the reason; the service doesn't start.
Secrets can come from the environment instead of the file (`ENV_MQTT_USERNAME`,
`ENV_MQTT_PASSWORD`).

    sections      one model per section of the file, each checking its own keys
    cross_checks  what involves several sections: unique names and unit ids, defined buses
    schema        the whole file's model (`GatewayConfig`)
    loading       YAML and the environment in, every problem out with its key path

Everything is imported from here (`from gateway.config import GatewayConfig`); only
`gateway.settings` turns it into what the running parts take.
"""

from gateway.config.loading import load_config, parse_config
from gateway.config.schema import GatewayConfig
from gateway.config.sections import (
    CONFIG_VERSIONS,
    DEFAULT_STATE_DIRECTORY,
    ENV_MQTT_PASSWORD,
    ENV_MQTT_USERNAME,
    ENV_STATE_DIRECTORY,
    STANDARD_BAUDRATES,
    AccessRuleConfig,
    AlarmConfig,
    BusConfig,
    ConsoleConfig,
    ConsoleUserConfig,
    DriveConfig,
    DriveReportConfig,
    FunctionCode,
    GatewayReportConfig,
    LoggingConfig,
    MetricsConfig,
    ModbusTcpConfig,
    ModbusTlsConfig,
    MqttConfig,
    PollGroupConfig,
    RegisterRange,
    Registers,
    ReportConfig,
    Rs485Config,
    Section,
    SparkplugConfig,
    StorageConfig,
    UnitId,
    Word,
    readable_file,
)

__all__ = [
    "CONFIG_VERSIONS",
    "DEFAULT_STATE_DIRECTORY",
    "ENV_MQTT_PASSWORD",
    "ENV_MQTT_USERNAME",
    "ENV_STATE_DIRECTORY",
    "STANDARD_BAUDRATES",
    "AccessRuleConfig",
    "AlarmConfig",
    "BusConfig",
    "ConsoleConfig",
    "ConsoleUserConfig",
    "DriveConfig",
    "DriveReportConfig",
    "FunctionCode",
    "GatewayConfig",
    "GatewayReportConfig",
    "LoggingConfig",
    "MetricsConfig",
    "ModbusTcpConfig",
    "ModbusTlsConfig",
    "MqttConfig",
    "PollGroupConfig",
    "RegisterRange",
    "Registers",
    "ReportConfig",
    "Rs485Config",
    "Section",
    "SparkplugConfig",
    "StorageConfig",
    "UnitId",
    "Word",
    "load_config",
    "parse_config",
    "readable_file",
]
