import asyncio

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.runtime.bus import Message, MessageBus, vehicle_time_of


def _item(i: int) -> Message:
    msg = mavlink.MAVLink_attitude_message(i, 0, 0, 0, 0, 0, 0)
    Encoder(1, 1).encode(msg)  # packed: it carries its wire bytes and header
    return Message.of(msg, float(i), float(i))


def test_slow_subscriber_drops_oldest_and_counts_while_others_get_everything():
    bus = MessageBus()
    slow = bus.subscribe("slow", maxlen=10)
    fast = bus.subscribe("fast", types=["ATTITUDE"], maxlen=100_000)
    other = bus.subscribe("other", types=["RAW_IMU"])
    for i in range(1000):
        bus.publish(_item(i))
    assert slow.dropped == 990
    assert [m.msg.time_boot_ms for m in slow.drain()] == list(range(990, 1000))
    assert len(fast.drain()) == 1000 and fast.dropped == 0
    assert other.delivered == 0


def test_subscriber_wakes_on_publish_and_unsubscribe_stops_delivery():
    async def scenario():
        bus = MessageBus()
        sub = bus.subscribe("s")
        waiter = asyncio.create_task(sub.get())
        await asyncio.sleep(0)
        bus.publish(_item(5))
        got = await asyncio.wait_for(waiter, 1)
        sub.close()
        bus.publish(_item(6))
        return got, sub.delivered

    got, delivered = asyncio.run(scenario())
    assert got.vehicle_time == 0.005 and delivered == 1


def test_vehicle_time_ignores_epoch_timestamps():
    gps = mavlink.MAVLink_gps_raw_int_message(1_700_000_000_000_000, 3, 0, 0, 0, 0, 0, 0, 0, 0)
    imu = mavlink.MAVLink_raw_imu_message(2_500_000, 0, 0, 0, 0, 0, 0, 0, 0, 0)
    assert vehicle_time_of(gps) is None
    assert vehicle_time_of(imu) == 2.5
    assert vehicle_time_of(mavlink.MAVLink_ahrs2_message(0, 0, 0, 0, 0, 0)) is None
