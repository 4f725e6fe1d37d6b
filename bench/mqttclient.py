"""Which MQTT client the gateway's MQTT output is built on: paho-mqtt 2 (its network
loop in a thread of its own) or aiomqtt (paho driven from the asyncio loop), timed
publishing to a local mosquitto, interleaved A B C A B C.

Each run is an asyncio loop standing in for the gateway's: it hands N records (a 0xC2
record's JSON, as the recording has it) to the client the way an output's ``take``
would, in bursts of 50 (a read's worth of records on a busy line), yielding between
bursts. What is timed:

- loop ms: CPU the loop's own thread spent on them (what every other output and the
  serial reader wait behind), per 1,000 records;
- process ms: CPU of the whole process (every thread), per 1,000 records;
- rec/s: records delivered to the broker's socket per second of wall time.

The three ways:

- ``paho-direct``: the loop calls paho's ``publish`` (packet made on the loop, queued
  for paho's thread, which it wakes through a socket pair: a syscall a record);
- ``paho-queue``: the loop appends to a bounded deque; a thread of ours publishes
  from it (woken once a burst), paho's thread writes;
- ``aiomqtt``: an asyncio task drains an asyncio.Queue and awaits aiomqtt's publish;
  everything, the socket's writes included, on the loop.

    .venv/bin/python bench/mqttclient.py [--records 20000] [--rounds 3]
    .venv/bin/python bench/mqttclient.py --sustain [--seconds 3]

``--sustain``: the gateway's MQTT output itself (gateway/daemon/outputs/mqtt.py, its
queue, its thread and paho's), given records at rising rates for ``--seconds`` each, a
fresh 0xC2 record each time (its JSON made in the output's thread, as in the gateway):
the records per second it sends into the broker, and how many it dropped, at each rate.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import resource
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import orjson
from benchutil import REPO

from gateway.common.jsontext import compact_bytes
from tests.helpers.broker import Broker

BURST = 50
PAYLOAD = compact_bytes({
    "node": 76, "record": "accel_angrate", "command": 0xC2, "seq": 123456,
    "host_time": 1764000000.123456, "lqi": 255, "rssi": -44, "station": "station1",
    "accel": [0.0123, -0.0045, -1.0002], "ang_rate": [0.0012, -0.0007, 0.0003],
    "timer": 123456789, "device_time": 6.279, "time": 1764000000.118})
TOPIC = "gx2/bench/76/accel_angrate"


async def _feed(n: int, take) -> None:
    for start in range(0, n, BURST):
        for _ in range(min(BURST, n - start)):
            take(PAYLOAD)
        await asyncio.sleep(0)


def _paho(port: int):
    from paho.mqtt.client import CallbackAPIVersion, Client
    client = Client(CallbackAPIVersion.VERSION2)
    written = [0]
    client.on_publish = lambda *_: written.__setitem__(0, written[0] + 1)
    client.connect("127.0.0.1", port)
    client.loop_start()
    while not client.is_connected():
        time.sleep(0.01)
    return client, written


async def paho_direct(port: int, n: int) -> tuple[float, int]:
    client, written = _paho(port)
    t0 = time.thread_time()
    await _feed(n, lambda payload: client.publish(TOPIC, payload))
    loop_cpu = time.thread_time() - t0
    while written[0] < n:
        await asyncio.sleep(0.001)
    client.loop_stop()
    client.disconnect()
    return loop_cpu, written[0]


async def paho_queue(port: int, n: int) -> tuple[float, int]:
    client, written = _paho(port)
    queue: collections.deque[bytes] = collections.deque(maxlen=100_000)
    wake = threading.Event()
    done = threading.Event()

    def drain() -> None:
        while not done.is_set():
            wake.wait(0.5)
            wake.clear()
            while queue:
                client.publish(TOPIC, queue.popleft())
    thread = threading.Thread(target=drain, daemon=True)
    thread.start()

    def take(payload: bytes) -> None:
        queue.append(payload)
        if not wake.is_set():
            wake.set()
    t0 = time.thread_time()
    await _feed(n, take)
    loop_cpu = time.thread_time() - t0
    while written[0] < n:
        await asyncio.sleep(0.001)
    done.set()
    wake.set()
    thread.join()
    client.loop_stop()
    client.disconnect()
    return loop_cpu, written[0]


async def aiomqtt_task(port: int, n: int) -> tuple[float, int]:
    import aiomqtt
    sent = [0]
    async with aiomqtt.Client("127.0.0.1", port) as client:
        queue: asyncio.Queue[bytes] = asyncio.Queue(maxsize=100_000)

        async def drain() -> None:
            while True:
                payload = await queue.get()
                await client.publish(TOPIC, payload)
                sent[0] += 1
        task = asyncio.create_task(drain())
        t0 = time.thread_time()
        await _feed(n, queue.put_nowait)
        while sent[0] < n:
            await asyncio.sleep(0.001)
        loop_cpu = time.thread_time() - t0
        task.cancel()
    return loop_cpu, sent[0]


def sustain(port: int, seconds: float) -> None:
    """Records per second the MQTT output delivers, offered at rising rates."""
    from gateway.common.topics import topic
    from gateway.daemon.config import MqttConfig
    from gateway.daemon.outputs import Message
    from gateway.daemon.outputs.mqtt import MqttOutput

    payload = orjson.loads(PAYLOAD)
    output = MqttOutput(MqttConfig(url=f"mqtt://127.0.0.1:{port}", name="bench"))
    output.start()
    while not output.connected:
        time.sleep(0.01)
    name = topic(76, "accel_angrate")
    print(f"{'offered/s':>10} {'sent/s':>8} {'dropped':>8} {'process CPU %':>14}")
    for rate in (1_000, 2_000, 4_000, 8_000, 16_000, 32_000):
        sent0, dropped0 = output.sent, sum(output.dropped.values())
        cpu0, t0 = _process_cpu(), time.monotonic()
        offered = 0
        while (elapsed := time.monotonic() - t0) < seconds:
            while offered < rate * elapsed:
                output.take(Message(name, {**payload, "seq": offered}))
                offered += 1
            time.sleep(0.005)  # (the pace of a loop's reads, not a synchronisation)
        wall = time.monotonic() - t0
        cpu = (_process_cpu() - cpu0) / wall * 100
        print(f"{offered / wall:10.0f} {(output.sent - sent0) / wall:8.0f} "
              f"{sum(output.dropped.values()) - dropped0:8d} {cpu:14.0f}", flush=True)
        if output.connects != 1 or output.error:
            print(f"  the broker: {output.status()}")
    output.close(2.0)


WAYS = {"paho-direct": paho_direct, "paho-queue": paho_queue, "aiomqtt": aiomqtt_task}


def _process_cpu() -> float:
    """CPU seconds of the process, threads that have ended included (getrusage: /proc's
    tasks forget a thread once it ends)."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def run(way: str, port: int, n: int) -> tuple[float, float, float]:
    """(loop CPU ms, process CPU ms, wall s) for ``n`` records."""
    cpu0, wall0 = _process_cpu(), time.monotonic()
    loop_cpu, sent = asyncio.run(WAYS[way](port, n))
    wall = time.monotonic() - wall0
    assert sent == n, (way, sent)
    return loop_cpu * 1000, (_process_cpu() - cpu0) * 1000, wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=20_000)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--sustain", action="store_true",
                        help="the gateway's MQTT output at rising rates")
    parser.add_argument("--seconds", type=float, default=3.0)
    args = parser.parse_args()
    if args.sustain:
        with tempfile.TemporaryDirectory() as directory:
            broker = Broker(Path(directory))
            try:
                sustain(broker.port, args.seconds)
            finally:
                broker.stop()
        print(f"\n{sys.executable} {Path(__file__).relative_to(REPO)} --sustain "
              f"--seconds {args.seconds:g}")
        return
    results: dict[str, list[tuple[float, float, float]]] = {way: [] for way in WAYS}
    with tempfile.TemporaryDirectory() as directory:
        broker = Broker(Path(directory))
        try:
            for _ in range(args.rounds):
                for way in WAYS:
                    results[way].append(run(way, broker.port, args.records))
        finally:
            broker.stop()
    k = args.records / 1000
    print(f"{'way':12} {'loop ms/1k':>11} {'process ms/1k':>14} {'rec/s':>8}")
    for way, runs in results.items():
        loop = statistics.median(r[0] for r in runs) / k
        process = statistics.median(r[1] for r in runs) / k
        rate = statistics.median(args.records / r[2] for r in runs)
        print(f"{way:12} {loop:11.1f} {process:14.1f} {rate:8.0f}")
    print(f"\n{sys.executable} {Path(__file__).relative_to(REPO)} --records {args.records} "
          f"--rounds {args.rounds}  (medians of the rounds, interleaved)")


if __name__ == "__main__":
    main()
