import pytest

from gcs.transport.address import Address, AddressError, parse_address


@pytest.mark.parametrize(
    "text, expected",
    [
        ("udpin:0.0.0.0:14550", Address("udpin", "0.0.0.0", 14550)),
        ("udp:0.0.0.0:14550", Address("udpin", "0.0.0.0", 14550)),
        ("udpout:192.168.1.5:14550", Address("udpout", "192.168.1.5", 14550)),
        ("tcp:127.0.0.1:5760", Address("tcp", "127.0.0.1", 5760)),
        ("tcpin:0.0.0.0:5760", Address("tcpin", "0.0.0.0", 5760)),
        ("/dev/ttyUSB0", Address("serial", path="/dev/ttyUSB0")),
        ("flight.tlog", Address("tlog", path="flight.tlog")),
        ("pty:/tmp/sim/tty", Address("pty", path="/tmp/sim/tty")),
    ],
)
def test_connection_strings_parse(text, expected):
    assert parse_address(text) == expected


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("udpin:0.0.0.0", "HOST:PORT"),
        ("tcp:localhost:http", "not a number"),
        ("udpout:1.2.3.4:70000", "outside"),
        ("bogus:1.2.3.4:5", "unknown scheme"),
        ("", "empty"),
    ],
)
def test_bad_connection_strings_say_what_is_wrong(text, fragment):
    with pytest.raises(AddressError, match=fragment):
        parse_address(text)
