"""pyserial URL handlers: sim:// opens the virtual device (protocol_sim).

Call register() once (rodctl.link.session does) so serial.serial_for_url("sim://...") finds it.
"""

PACKAGE = __name__


def register() -> None:
    import serial

    if PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(PACKAGE)
