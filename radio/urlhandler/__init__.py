"""pyserial URL handlers (`serial.protocol_handler_packages`; `radio.ports.open_url` adds this package)."""
