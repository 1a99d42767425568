"""A TCP relay that delays what it carries: a slow link where the kernel has no ``sch_netem``.

    python -m arcf.loadtools.relay --listen 10.213.20.1:7447 --to 127.0.0.1:7447 --delay-ms 20

Every connection accepted on ``--listen`` is carried to ``--to``, each way, every chunk
held ``--delay-ms`` after it was read (order kept) while the delay is on. SIGUSR1 turns the
delay on, SIGUSR2 off (it starts off unless ``--on``), so that a test switches a link
between fast and slow without breaking its connections. Loss belongs to the kernel
(:meth:`arcf.loadtools.netlab.NetLab.lose`), which drops packets that TCP then retransmits;
a relay dropping bytes would break the stream instead.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
import sys


class Delay:
    """The relay's one-way delay now (seconds)."""

    def __init__(self, seconds: float, on: bool) -> None:
        self.when_on = seconds
        self.seconds = seconds if on else 0.0


async def _carry(reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                 delay: Delay) -> None:
    """One direction: every chunk read goes out ``delay.seconds`` later, in order."""
    loop = asyncio.get_running_loop()
    held: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue()

    async def send() -> None:
        while True:
            due, data = await held.get()
            if not data:
                break
            wait = due - loop.time()
            if wait > 0:
                await asyncio.sleep(wait)
            writer.write(data)
            await writer.drain()

    sender = asyncio.create_task(send())
    try:
        while data := await reader.read(1 << 16):
            held.put_nowait((loop.time() + delay.seconds, data))
    except ConnectionError:
        pass
    finally:
        held.put_nowait((0.0, b""))
        with contextlib.suppress(ConnectionError):
            await sender
        writer.close()


async def serve(listen: tuple[str, int], to: tuple[str, int], delay: Delay) -> None:
    async def connection(down_r: asyncio.StreamReader, down_w: asyncio.StreamWriter) -> None:
        try:
            up_r, up_w = await asyncio.open_connection(*to)
        except OSError:
            down_w.close()
            return
        await asyncio.gather(_carry(down_r, up_w, delay), _carry(up_r, down_w, delay),
                             return_exceptions=True)

    server = await asyncio.start_server(connection, *listen)
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    loop.add_signal_handler(signal.SIGUSR1, lambda: setattr(delay, "seconds", delay.when_on))
    loop.add_signal_handler(signal.SIGUSR2, lambda: setattr(delay, "seconds", 0.0))
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    loop.add_signal_handler(signal.SIGINT, stop.set)
    print(f"relay ready: {listen[0]}:{listen[1]} -> {to[0]}:{to[1]}", flush=True)
    async with server:
        await stop.wait()


def _address(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    return host, int(port)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--listen", required=True, type=_address, metavar="HOST:PORT")
    ap.add_argument("--to", required=True, type=_address, metavar="HOST:PORT")
    ap.add_argument("--delay-ms", type=float, default=20.0, help="one way, while on")
    ap.add_argument("--on", action="store_true", help="start with the delay on")
    args = ap.parse_args(argv)
    asyncio.run(serve(args.listen, args.to, Delay(args.delay_ms / 1e3, args.on)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
