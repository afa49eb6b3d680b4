"""Kept so `from rodctl.cli.device import ...` still works: the device commands now live in status, record,
console, simdevice and logconvert, and what they share in rodctl.cli.common. Not a command module."""

from rodctl.cli.common import (ARM_CHOICES, PORT_HELP, add_design_args, add_port_arg, apply_settings,  # noqa: F401
                               design_params, mode_text, no_interrupts, session_for, status_text, stop_signals)
