"""The configuration: one YAML file, validated completely at load, including cross-field checks.

The key names are a public interface (users' files depend on them): add, never rename. A file that
doesn't validate raises ConfigError naming each key path and the reason; the service doesn't start.
Secrets can come from the environment instead of the file (`ENV_MQTT_USERNAME`,
`ENV_MQTT_PASSWORD`).

    sections      one model per section of the file, each checking its own keys (a module
                  per subject: buses, drives, modbus_tcp, mqtt, console, storage...)
    cross_checks  what involves several sections: unique names and unit ids, defined buses
    schema        the whole file's model (`GatewayConfig`)
    loading       YAML and the environment in, every problem out with its key path

Everything is imported from here (`from gateway.config import GatewayConfig`); only
`gateway.settings` turns it into what the running parts take.
"""

from gateway.config.loading import load_config, parse_config
from gateway.config.schema import CONFIG_VERSIONS, GatewayConfig
from gateway.config.sections.buses import STANDARD_BAUDRATES, BusConfig, Rs485Config
from gateway.config.sections.console import ConsoleConfig, ConsoleUserConfig
from gateway.config.sections.drives import AlarmConfig, DriveConfig, PollGroupConfig
from gateway.config.sections.modbus_tcp import AccessRuleConfig, ModbusTcpConfig, ModbusTlsConfig
from gateway.config.sections.monitoring import LoggingConfig, MetricsConfig
from gateway.config.sections.mqtt import (
    ENV_MQTT_PASSWORD,
    ENV_MQTT_USERNAME,
    MqttConfig,
    SparkplugConfig,
)
from gateway.config.sections.opcua import OpcUaConfig
from gateway.config.sections.reports import DriveReportConfig, GatewayReportConfig, ReportConfig
from gateway.config.sections.section import Section, readable_file
from gateway.config.sections.storage import (
    DEFAULT_STATE_DIRECTORY,
    ENV_STATE_DIRECTORY,
    StorageConfig,
)
from gateway.config.sections.values import FunctionCode, RegisterRange, Registers, UnitId, Word

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
    "OpcUaConfig",
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
