"""Stream latency of ``graytrack serve`` on the virtual rig, per frame rate and number of clients.

For each frame rate (200, 500, 1000, 1500 frames/s) and 1 or 4 WebSocket clients, a daemon is
started as its own process (sim clock at wall speed, the model of one shared calibration), the
clients run in another process and, for a few seconds, record per message the receipt time minus
the message's ``t`` (mid-exposure; both on this machine's ``time.monotonic``), ``seq`` gaps and
the daemon's ``dropped`` count (camera frames missing from the stream). The daemon's CPU is read
from /proc. All figures come from the same run, so they compare with each other on a shared machine.

Run: .venv/bin/python bench/stream_latency.py [--seconds 5] [--rates 200,500,1000,1500] [--clients 1,4]
     [--models auto,paper] [--effects dust:count=6,prnu:sigma=0.02]  (the closed loop's model against the
                            seed paper's, side by side, on a rig with those effects)
     [--polls 0.005,0.02]   (grating poll periods compared side by side)
     [--deflate 0,1]        (the WebSocket's permessage-deflate off and on, side by side)
     [--priority 0,10]      (the daemon's realtime_priority, and the clients': normal or SCHED_FIFO 10, side by side)
     [--client-offsets 0,1] (the clients' SCHED_FIFO level against the daemon's: the same, or one above, so
                            that their wake-up preempts the virtual rig's renderer on their core; side by side)
     [--load 2]             (that many busy-looping processes run meanwhile: a machine with other work)
     [--scenario strip16 --rows 16]  (the virtual rig's scenario and the ROI's rows: a 16-row strip)
     [--renders fast,direct] (the virtual camera's one-frame renderer against the rig's direct render,
                            side by side: GRAYTRACK_SIM_RENDER, drivers/sim/frame_render.py)
     [--rig-process 0,1]    (the virtual rig in the daemon's process against in its own, side by side:
                            [camera] rig_process, drivers/sim/process.py)
     [--repeat 5]           (rounds of every configuration, interleaved; medians at the end)
     [--pin 0,1]            (the daemon on a core of its own, [daemon] cpu_cores, the rig's process and the
                            clients on the others, against unpinned, side by side)
     [--client websockets,socket] (the websockets library's asyncio clients against a selector on raw
                            sockets that stamps each read as it returns, side by side)

``CPU %`` is the daemon's process, ``rig %`` the virtual rig's process when it has one (its stage,
controller and rendering: what real hardware does outside the host).

Besides the receipt latency it prints ``enc``: mid-exposure to the message's encoding in the daemon
(its ``age_ms``), so a tail can be placed before (frame thread) or after (event loop, send, client) it,
and the client process's own CPU (it shares the machine's cores with the daemon).

``host99``/``hostmax``/``steal%``: the host's own floor in the same seconds (bench/host_floor.py: a
thread one SCHED_FIFO level above the daemon's, on the daemon's core, sleeping 1 ms; its lateness is
the kernel's and the hypervisor's, which no thread of the run can cause), and the time the host ran
other guests. A message's p99 cannot beat its pipeline's median by less than that floor's p99.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

CLIENT = r"""
import asyncio, json, sys, time
from websockets.asyncio.client import connect

async def client(url, seconds, out):
    async with connect(url, max_queue=None) as ws:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            text = await ws.recv()
            now = time.monotonic()
            m = json.loads(text)
            # age_ms: mid-exposure to encoding, in the daemon
            out.append((now - m["t"], m["seq"], m["dropped"], m["age_ms"]))

async def main(url, n, seconds):
    outs = [[] for _ in range(n)]
    cpu0, wall0 = time.process_time(), time.monotonic()
    await asyncio.gather(*(client(url, seconds, out) for out in outs))
    print(json.dumps({"outs": outs, "cpu": (time.process_time() - cpu0) / (time.monotonic() - wall0)}))

asyncio.run(main(sys.argv[1], int(sys.argv[2]), float(sys.argv[3])))
"""


# The same measurement with the receipt stamped at the socket: one thread reads the N connections
# through a selector, stamps each read when it returns, then parses the WebSocket frames it holds
# (a server's frames are unmasked; pings answered). A motion controller in C, or on another host,
# pays no Python WebSocket library per message; this client's own per-message cost stays out of
# the stamps of the messages that arrived with it.
SOCKET_CLIENT = r"""
import base64, json, os, selectors, socket, struct, sys, time
from urllib.parse import urlparse

def connect(url):
    u = urlparse(url)
    sock = socket.create_connection((u.hostname, u.port))
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall((f"GET {u.path} HTTP/1.1\r\nHost: {u.hostname}:{u.port}\r\nUpgrade: websocket\r\n"
                  f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())
    head = b""
    while b"\r\n\r\n" not in head:
        head += sock.recv(4096)
    head, rest = head.split(b"\r\n\r\n", 1)
    if b" 101 " not in head.split(b"\r\n")[0]:
        raise SystemExit(f"no WebSocket upgrade: {head[:200]!r}")
    sock.setblocking(False)
    return sock, rest

def masked(opcode, payload):
    mask = os.urandom(4)
    body = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
    return bytes([0x80 | opcode, 0x80 | len(payload)]) + mask + body

def frames(buffer):
    # complete frames in buffer: (opcode, payload) list and the bytes left over
    out, at = [], 0
    while len(buffer) - at >= 2:
        opcode, size = buffer[at] & 0x0F, buffer[at + 1] & 0x7F
        start = at + 2
        if size == 126:
            if len(buffer) - start < 2: break
            size, start = struct.unpack_from("!H", buffer, start)[0], start + 2
        elif size == 127:
            if len(buffer) - start < 8: break
            size, start = struct.unpack_from("!Q", buffer, start)[0], start + 8
        if len(buffer) - start < size: break
        out.append((opcode, buffer[start:start + size]))
        at = start + size
    return out, buffer[at:]

def main(url, n, seconds):
    selector = selectors.DefaultSelector()
    outs, buffers = [[] for _ in range(n)], {}
    for k in range(n):
        sock, rest = connect(url)
        buffers[sock] = (k, rest)
        selector.register(sock, selectors.EVENT_READ)
    cpu0, wall0 = time.process_time(), time.monotonic()
    end = wall0 + seconds
    while time.monotonic() < end:
        for key, _ in selector.select(timeout=0.1):
            sock = key.fileobj
            data = sock.recv(1 << 20)
            now = time.monotonic()
            k, held = buffers[sock]
            found, held = frames(held + data)
            buffers[sock] = (k, held)
            for opcode, payload in found:
                if opcode == 1:
                    m = json.loads(payload)
                    outs[k].append((now - m["t"], m["seq"], m["dropped"], m["age_ms"]))
                elif opcode == 9:
                    sock.setblocking(True); sock.sendall(masked(10, payload)); sock.setblocking(False)
    for sock in list(buffers):
        sock.setblocking(True)
        sock.sendall(masked(8, struct.pack("!H", 1000)))
        sock.close()
    print(json.dumps({"outs": outs, "cpu": (time.process_time() - cpu0) / (time.monotonic() - wall0)}))

main(sys.argv[1], int(sys.argv[2]), float(sys.argv[3]))
"""
CLIENTS = {"websockets": CLIENT, "socket": SOCKET_CLIENT}


CORES = sorted(os.sched_getaffinity(0))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def config(folder: Path, rate: float, poll_s: float = 0.005, deflate: bool = False, priority: int = 0,
           model: str = "auto", effects: str = "", scenario: str = "paper", rows: int = 1, rig_process: bool = True,
           pin: bool = False) -> Path:
    """The daemon's configuration; each model kind (and rig, and exposure) keeps its own data
    directory, so its one calibration (made at the first start) serves every run of that kind."""
    path = folder / (f"{model}-{scenario}-rows{rows}-rate{rate:g}-poll{poll_s:g}-deflate{int(deflate)}"
                     f"-prio{priority}-rp{int(rig_process)}-pin{int(pin)}.toml")
    exposure_us = min(1000.0, 0.5e6 / rate)  # the rig's 1 ms exposure fits up to 1000 frames/s
    path.write_text(f'[camera]\nkind = "sim"\nframe_rate_hz = {rate}\nexposure_us = {exposure_us}\n'
                    f'effects = "{effects}"\nscenario = "{scenario}"\nrig_process = {str(rig_process).lower()}\n'
                    f'[camera.roi]\nrows = {rows}\n'
                    f'[sweep]\nmodel = "{model}"\n'
                    '[daemon]\ndata_dir = '
                    f'"{folder / ("data-" + model + "-" + scenario + str(rows) + f"-{exposure_us:g}us")}"\nlog_level = '
                    f'"warning"\ngrating_poll_s = {poll_s}\n'
                    f'ws_compression = {str(deflate).lower()}\nrealtime_priority = {priority}\n'
                    f'cpu_cores = {CORES[-1:] if pin else []}\n')
    return path


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def children(pid: int) -> list[int]:
    """The direct child processes of ``pid`` (the virtual rig's, when it runs apart)."""
    found = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            found += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            pass
    return found


def wait_tracking(base: str, timeout_s: float = 300.0) -> dict:
    """The daemon's status once it tracks (a model it calls stale still streams: latency is measured
    all the same, and the row says so)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            status = httpx.get(f"{base}/api/status", timeout=2).json()
            if status.get("state") == "tracking":
                return status
        except (httpx.TransportError, ValueError):
            pass
        time.sleep(0.2)
    raise SystemExit(f"the daemon at {base} did not start tracking within {timeout_s:g} s")


def run(folder: Path, rate: float, clients: int, seconds: float, poll_s: float = 0.005,
        deflate: bool = False, priority: int = 0, model: str = "auto", effects: str = "", scenario: str = "paper",
        rows: int = 1, render: str = "fast", rig_process: bool = True, client: str = "websockets",
        pin: bool = False, client_offset: int = 0) -> dict[str, float]:
    port = free_port()
    log = (folder / f"serve-{model}-{rate:g}-{clients}.log").open("w")
    daemon = subprocess.Popen([sys.executable, "-m", "graytrack", "serve", "--config",
                               str(config(folder, rate, poll_s, deflate, priority, model, effects, scenario, rows,
                                          rig_process, pin)),
                               "--port", str(port)], stderr=log, env={**os.environ, "GRAYTRACK_SIM_RENDER": render})
    try:
        status = wait_tracking(f"http://127.0.0.1:{port}")
        time.sleep(0.5)
        rigs = children(daemon.pid)
        cpu0, rig0, wall0 = cpu_seconds(daemon.pid), sum(map(cpu_seconds, rigs)), time.monotonic()
        # the clients get the daemon's priority: a motion controller that waits for a core measures its own delay
        def raise_client() -> None:
            if priority:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority + client_offset))
            if pin:  # beside the daemon's core, as the rig's process (a client on another host, as it were)
                os.sched_setaffinity(0, CORES[:-1])
        # the host's own floor in the same seconds, on the daemon's core, above every thread of the run
        floor = subprocess.Popen([sys.executable, str(Path(__file__).with_name("host_floor.py")), "--json",
                                  "--seconds", str(seconds), "--core", str(CORES[-1]),
                                  "--priority", str(priority + 1 if priority else 0)], stdout=subprocess.PIPE,
                                 text=True)
        result = subprocess.run([sys.executable, "-c", CLIENTS[client], f"ws://127.0.0.1:{port}/ws/position",
                                 str(clients), str(seconds)],
                                capture_output=True, text=True, check=True, preexec_fn=raise_client)
        host = json.loads(floor.communicate(timeout=seconds + 30)[0])
        wall = time.monotonic() - wall0
        cpu = (cpu_seconds(daemon.pid) - cpu0) / wall
        rig_cpu = (sum(map(cpu_seconds, rigs)) - rig0) / wall
    finally:
        daemon.terminate()
        daemon.wait(timeout=30)
        log.close()
    measured = json.loads(result.stdout)
    outs = measured["outs"]
    latency = np.concatenate([[m[0] for m in out] for out in outs]) * 1e3
    encoded = np.concatenate([[m[3] for m in out] for out in outs])  # mid-exposure to encoded, in the daemon
    missing = sum(int(np.sum(np.diff([m[1] for m in out]) - 1)) for out in outs)
    dropped = max(out[-1][2] - out[0][2] for out in outs)
    return {"rate": rate, "clients": clients, "msgs_s": np.mean([len(out) for out in outs]) / seconds,
            "missing": missing, "dropped": dropped, "p50": np.percentile(latency, 50),
            "p99": np.percentile(latency, 99), "max": latency.max(), "cpu": 100 * cpu, "rig_cpu": 100 * rig_cpu,
            "client_cpu": 100 * measured["cpu"], "enc50": np.percentile(encoded, 50),
            "enc99": np.percentile(encoded, 99),
            "stale": status.get("stale_reason") or "-" if status.get("model_stale") else "-",
            "host99": host["p99"], "host_max": host["max"], "steal": host["steal_pct"]}


def host_summary(runs: list[dict[str, float]], quiet_steal_pct: float = 0.5) -> str:
    """How the tail follows the host: the rank correlation of p99 with the time the host ran other
    guests, over every run, and the runs in which it ran them for less than ``quiet_steal_pct``."""
    p99, steal = np.array([r["p99"] for r in runs]), np.array([r["steal"] for r in runs])
    ranks = [np.argsort(np.argsort(values)) for values in (p99, steal)]
    rho = float(np.corrcoef(*ranks)[0, 1])
    quiet = [r for r in runs if r["steal"] < quiet_steal_pct]
    said = ", ".join(f"p99 {r['p99']:.2f} ms ({r['dropped']} dropped)" for r in quiet) or "none"
    return (f"p99 against the host's steal over {len(runs)} runs: rank correlation {rho:+.2f}; "
            f"runs with steal < {quiet_steal_pct:g} %: {said}")


def load_average() -> str:
    return Path("/proc/loadavg").read_text().split()[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--rates", default="200,500,1000,1500")
    parser.add_argument("--clients", default="1,4")
    parser.add_argument("--deflate", default="0", help="permessage-deflate off/on (0,1) to compare, side by side")
    parser.add_argument("--polls", default="0.005", help="grating poll periods (s) to compare, side by side")
    parser.add_argument("--priority", default="0",
                        help="the daemon's realtime_priority values to compare, side by side")
    parser.add_argument("--client-offsets", default="0", help="the clients' SCHED_FIFO level over the daemon's "
                        "(with --priority above 0), side by side: 0,1")
    parser.add_argument("--load", type=int, default=0, help="busy-looping processes to run meanwhile")
    parser.add_argument("--models", default="auto", help="the sweep's model kinds to compare, side by side "
                        "(auto: the closed loop's model, what the daemon installs by default; paper)")
    parser.add_argument("--effects", default="", help="the virtual rig's effects (what the closed loop then models), "
                        "e.g. dust:count=6,prnu:sigma=0.02")
    parser.add_argument("--scenario", default="paper", help="the virtual rig's scenario (strip16, highspeed: 16 rows)")
    parser.add_argument("--rows", type=int, default=1, help="rows of the camera's ROI (16 for a 16-row model)")
    parser.add_argument("--renders", default="fast", help="the virtual camera's renderer(s) to compare, side by side: "
                        "fast (one frame, precomputed) and/or direct (VirtualRig.render)")
    parser.add_argument("--client", default="websockets", help="the clients compared, side by side: websockets (the "
                        "websockets library's asyncio client) and/or socket (a selector on raw sockets, the receipt "
                        "stamped as the read returns)")
    parser.add_argument("--repeat", type=int, default=1, help="rounds of every configuration, interleaved, with "
                        "the medians at the end (one run's p99 swings several-fold on a shared machine)")
    parser.add_argument("--pin", default="0",
                        help="the daemon on a core of its own ([daemon] cpu_cores: the last), the "
                        "rig's process and the clients on the others (1), or where the kernel puts them (0); side by "
                        "side: 0,1")
    parser.add_argument("--rig-process", default="1",
                        help="the virtual rig in its own process (1) or the daemon's (0), "
                        "side by side: 0,1")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="graytrack-bench-"))
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.load)]
    try:
        # one calibration per model kind and exposure (the daemon calibrates itself at the first start), reused
        # by every run at that exposure: a model calibrated at another exposure sees other images (motion
        # blur, light) and rightly works harder on every frame, which is not what a lab running one rate pays
        models = args.models.split(",")
        for model in models:
            for rate in {min(1000.0, 0.5e6 / float(r)): float(r) for r in args.rates.split(",")}.values():
                run(folder, rate, 1, 0.5, model=model, effects=args.effects, scenario=args.scenario, rows=args.rows)
        print(f"machine: {os.cpu_count()} cores, load average {load_average()} at start, "
              f"{args.load} busy-looping processes meanwhile; scenario {args.scenario}, {args.rows} row(s)")
        print(f"{'pin':>3} {'client':>10} {'rig':>4} {'render':>6} {'model':>6} {'prio':>4} {'deflate':>7} "
              f"{'poll ms':>7} {'frames/s':>8} {'clients':>7} {'cl+':>3} {'msgs/s':>8} {'missing':>7} {'dropped':>7} "
              f"{'p50 ms':>7} {'p99 ms':>7} {'max ms':>7} {'CPU %':>6} {'rig %':>6} {'cl CPU':>6} {'enc p50':>7} "
              f"{'enc p99':>7} {'host99':>6} {'hostmax':>7} {'steal%':>6} {'stale':>9}")
        configurations = [(rate, clients, n == "1", c, a == "1", e, m, float(p), d == "1", int(q), int(o))
                          for rate in (float(r) for r in args.rates.split(",")) for clients in
                          (int(c) for c in args.clients.split(",")) for n in args.pin.split(",")
                          for c in args.client.split(",") for a in args.rig_process.split(",")
                          for e in args.renders.split(",") for m in models for p in args.polls.split(",")
                          for d in args.deflate.split(",") for q in args.priority.split(",")
                          for o in args.client_offsets.split(",")]
        results: dict[tuple, list[dict[str, float]]] = {}
        for _ in range(args.repeat):  # the configurations interleaved, round after round
            for setup in configurations:
                rate, clients, pin, client, apart, render, model, poll, deflate, prio, offset = setup
                r = run(folder, rate, clients, args.seconds, poll, deflate, prio, model, args.effects,
                        args.scenario, args.rows, render, apart, client, pin, offset)
                results.setdefault(setup, []).append(r)
                print(f"{'yes' if pin else 'no':>3} {client:>10} {'own' if apart else 'in':>4} {render:>6} {model:>6} "
                      f"{prio:4d} {'on' if deflate else 'off':>7} {poll * 1e3:7.1f} {r['rate']:8.0f} {r['clients']:7d} "
                      f"{offset:3d} {r['msgs_s']:8.0f} {r['missing']:7d} {r['dropped']:7d} "
                      f"{r['p50']:7.2f} {r['p99']:7.2f} {r['max']:7.2f} {r['cpu']:6.0f} {r['rig_cpu']:6.0f} "
                      f"{r['client_cpu']:6.0f} {r['enc50']:7.2f} {r['enc99']:7.2f} {r['host99']:6.2f} "
                      f"{r['host_max']:7.2f} {r['steal']:6.2f} {r['stale']:>9}",
                      flush=True)
        if args.repeat > 1:
            print(f"\nmedians over {args.repeat} rounds (p99: its median and range; runs with no camera frame dropped)")
            for (rate, clients, pin, client, apart, *_, prio, offset), runs in results.items():
                p99 = np.array([r["p99"] for r in runs])
                print(f"{'yes' if pin else 'no':>3} {client:>10} {'own' if apart else 'in':>4} {rate:8.0f} frames/s "
                      f"prio {prio}, clients +{offset}: {clients} clients: p50 "
                      f"{np.median([r['p50'] for r in runs]):.2f} ms, p99 {np.median(p99):.2f} ms "
                      f"({p99.min():.2f}-{p99.max():.2f}), enc p99 {np.median([r['enc99'] for r in runs]):.2f} ms, CPU "
                      f"{np.median([r['cpu'] for r in runs]):.0f} %, "
                      f"{sum(r['dropped'] == 0 for r in runs)} of {len(runs)} runs without a drop; the host's own "
                      f"wake-up p99 (bench/host_floor.py) {np.median([r['host99'] for r in runs]):.2f} ms")
        every = [r for runs in results.values() for r in runs]
        if len(every) > 2:
            print(host_summary(every))
        print(f"load average {load_average()} at the end")
    finally:
        for burner in burners:
            burner.kill()
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
