"""Links to a vehicle: transports, MAVLink framing, link state and counters, forwarding."""
