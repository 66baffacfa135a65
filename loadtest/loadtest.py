#!/usr/bin/env python3
"""Load driver for rigserve: N concurrent clients run the full client flow (upload,
follow by polling or SSE, download) against a running server, while a separate poller
measures status-poll latency. Prints a JSON report: throughput, latency percentiles,
errors, lost jobs, and the server's peak RSS (when --pid is given, from /proc).

Standard library only, so it runs anywhere Python 3.9+ does.

    python3 loadtest/loadtest.py --url http://127.0.0.1:8080 --clients 32 \
        --duration 60 --mesh ../shared/rigs/<file>.glb --pid $(pgrep -f 'rigserve serve')
"""
import argparse
import http.client
import json
import os
import statistics
import sys
import threading
import time
import urllib.parse


def pct(xs, p):
    if not xs:
        return None
    xs = sorted(xs)
    k = min(len(xs) - 1, max(0, int(round(p / 100.0 * (len(xs) - 1)))))
    return xs[k]


def summary_ms(xs):
    return {
        "n": len(xs),
        "p50_ms": round(pct(xs, 50) * 1e3, 2) if xs else None,
        "p90_ms": round(pct(xs, 90) * 1e3, 2) if xs else None,
        "p99_ms": round(pct(xs, 99) * 1e3, 2) if xs else None,
        "max_ms": round(max(xs) * 1e3, 2) if xs else None,
        "mean_ms": round(statistics.mean(xs) * 1e3, 2) if xs else None,
    }


class Conn:
    """One keep-alive connection per client thread."""

    def __init__(self, base, token=None, timeout=300):
        u = urllib.parse.urlparse(base)
        self.host, self.port = u.hostname, u.port or 80
        self.timeout = timeout
        self.token = token
        self.c = None

    def request(self, method, path, body=None, headers=None):
        h = dict(headers or {})
        if self.token:
            h["Authorization"] = "Bearer " + self.token
        for attempt in range(2):
            if self.c is None:
                self.c = http.client.HTTPConnection(self.host, self.port, timeout=self.timeout)
            try:
                self.c.request(method, path, body=body, headers=h)
                r = self.c.getresponse()
                data = r.read()
                return r.status, dict(r.getheaders()), data
            except (http.client.HTTPException, ConnectionError, OSError):
                self.c.close()
                self.c = None
                if attempt == 1:
                    raise
        raise RuntimeError("unreachable")

    def stream(self, path, headers=None):
        """Reads an SSE stream to its end; returns the parsed events."""
        c = http.client.HTTPConnection(self.host, self.port, timeout=self.timeout)
        h = dict(headers or {})
        if self.token:
            h["Authorization"] = "Bearer " + self.token
        c.request("GET", path, headers=h)
        r = c.getresponse()
        events, cur = [], {}
        while True:
            line = r.readline()
            if not line:
                break
            line = line.decode().rstrip("\r\n")
            if line == "":
                if "data" in cur:
                    events.append(cur)
                cur = {}
            elif line.startswith("id:"):
                cur["id"] = line[3:].strip()
            elif line.startswith("data:"):
                cur["data"] = json.loads(line[5:].strip())
        c.close()
        return r.status, events


class Stats:
    def __init__(self):
        self.lock = threading.Lock()
        self.submitted = []  # job ids accepted (202)
        self.completed = {}  # id -> final status
        self.downloaded = 0
        self.job_latency = []  # submit -> result downloaded, seconds
        self.submit_latency = []
        self.poll_latency = []  # by the client threads
        self.probe_latency = []  # by the dedicated poller, while jobs run
        self.status_codes = {}
        self.errors = []

    def code(self, c):
        with self.lock:
            self.status_codes[c] = self.status_codes.get(c, 0) + 1


def client_loop(args, mesh, ctype, stats, stop_at, idx):
    conn = Conn(args.url, args.token)
    n = 0
    while time.time() < stop_at:
        n += 1
        t0 = time.time()
        q = "?seed=%d" % (idx * 100000 + n)
        try:
            st, hdr, body = conn.request("POST", "/v1/jobs" + q, mesh, {"Content-Type": ctype})
        except Exception as e:  # noqa: BLE001 - a load driver records every failure
            with stats.lock:
                stats.errors.append("submit: %r" % e)
            continue
        stats.code(st)
        stats.submit_latency.append(time.time() - t0)
        if st == 429:
            time.sleep(float(hdr.get("retry-after", hdr.get("Retry-After", "1"))))
            continue
        if st != 202:
            with stats.lock:
                stats.errors.append("submit %d: %s" % (st, body[:200]))
            continue
        job = json.loads(body)
        jid = job["id"]
        with stats.lock:
            stats.submitted.append(jid)
        final = None
        try:
            if args.follow == "sse":
                st, events = conn.stream("/v1/jobs/%s/events" % jid)
                stats.code(st)
                if events:
                    final = events[-1]["data"]["status"]
            while final in (None, "queued", "running"):
                t1 = time.time()
                st, _, body = conn.request("GET", "/v1/jobs/" + jid)
                stats.poll_latency.append(time.time() - t1)
                stats.code(st)
                if st != 200:
                    break
                final = json.loads(body)["status"]
                if final in ("queued", "running"):
                    time.sleep(args.poll_interval)
            with stats.lock:
                stats.completed[jid] = final
            if final == "succeeded":
                st, _, glb = conn.request("GET", "/v1/jobs/%s/result.glb" % jid)
                stats.code(st)
                if st == 200 and glb[:4] == b"glTF":
                    with stats.lock:
                        stats.downloaded += 1
                        stats.job_latency.append(time.time() - t0)
                else:
                    with stats.lock:
                        stats.errors.append("download %s: %d" % (jid, st))
        except Exception as e:  # noqa: BLE001
            with stats.lock:
                stats.errors.append("follow %s: %r" % (jid, e))


def prober(args, stats, stop_at):
    """Polls the status of the most recent job at a fixed rate while the run lasts."""
    conn = Conn(args.url, args.token)
    while time.time() < stop_at:
        with stats.lock:
            jid = stats.submitted[-1] if stats.submitted else None
        if jid:
            t = time.time()
            try:
                st, _, _ = conn.request("GET", "/v1/jobs/" + jid)
                stats.probe_latency.append(time.time() - t)
                stats.code(st)
            except Exception as e:  # noqa: BLE001
                with stats.lock:
                    stats.errors.append("probe: %r" % e)
        time.sleep(0.02)


def rss_watch(pid, out, stop):
    while not stop.is_set():
        try:
            with open("/proc/%d/status" % pid) as f:
                for line in f:
                    if line.startswith("VmHWM:"):
                        out["peak_rss_mib"] = round(int(line.split()[1]) / 1024.0, 1)
                    if line.startswith("VmRSS:"):
                        rss = int(line.split()[1]) / 1024.0
                        out["max_rss_seen_mib"] = round(max(out.get("max_rss_seen_mib", 0), rss), 1)
        except OSError:
            pass
        stop.wait(0.5)


def cpu_seconds(pid):
    try:
        with open("/proc/%d/stat" % pid) as f:
            parts = f.read().rsplit(")", 1)[1].split()
        return (int(parts[11]) + int(parts[12])) / os.sysconf("SC_CLK_TCK")
    except OSError:
        return None


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", default="http://127.0.0.1:8080")
    ap.add_argument("--clients", type=int, default=32)
    ap.add_argument("--duration", type=float, default=60, help="seconds of submitting; running jobs are then awaited")
    ap.add_argument("--mesh", required=True, help="mesh file to upload (GLB, glTF, VRM, OBJ)")
    ap.add_argument("--follow", choices=["poll", "sse"], default="poll")
    ap.add_argument("--poll-interval", type=float, default=0.2)
    ap.add_argument("--token", default=None, help="API key")
    ap.add_argument("--pid", type=int, action="append", default=[], help="server process(es) to watch for RSS and CPU")
    ap.add_argument("--out", default=None, help="also write the JSON report here")
    a = ap.parse_args()

    mesh = open(a.mesh, "rb").read()
    ctype = "model/obj" if a.mesh.lower().endswith(".obj") else "application/octet-stream"
    stats = Stats()
    start = time.time()
    stop_at = start + a.duration
    rss = {p: {} for p in a.pid}
    cpu0 = {p: cpu_seconds(p) for p in a.pid}
    stop_rss = threading.Event()
    watchers = [threading.Thread(target=rss_watch, args=(p, rss[p], stop_rss), daemon=True) for p in a.pid]
    for w in watchers:
        w.start()
    threads = [threading.Thread(target=client_loop, args=(a, mesh, ctype, stats, stop_at, i)) for i in range(a.clients)]
    threads.append(threading.Thread(target=prober, args=(a, stats, stop_at), daemon=True))
    for t in threads:
        t.start()
    for t in threads[:-1]:
        t.join()
    elapsed = time.time() - start
    stop_rss.set()

    lost = [j for j in stats.submitted if stats.completed.get(j) != "succeeded"]
    fivexx = sum(n for c, n in stats.status_codes.items() if 500 <= c < 600)
    report = {
        "clients": a.clients,
        "follow": a.follow,
        "mesh": os.path.basename(a.mesh),
        "mesh_bytes": len(mesh),
        "elapsed_s": round(elapsed, 1),
        "jobs_submitted": len(stats.submitted),
        "jobs_succeeded": stats.downloaded,
        "jobs_not_succeeded": len(lost),
        "jobs_per_min": round(stats.downloaded / elapsed * 60.0, 1),
        "http_5xx": fivexx,
        "status_codes": {str(k): v for k, v in sorted(stats.status_codes.items())},
        "errors": stats.errors[:20],
        "error_count": len(stats.errors),
        "job_latency": summary_ms(stats.job_latency),
        "submit_latency": summary_ms(stats.submit_latency),
        "status_poll_latency": summary_ms(stats.poll_latency + stats.probe_latency),
        "servers": {
            str(p): dict(rss[p], cpu_s=round((cpu_seconds(p) or 0) - (cpu0[p] or 0), 1),
                         cpu_cores_used=round(((cpu_seconds(p) or 0) - (cpu0[p] or 0)) / elapsed, 2))
            for p in a.pid
        },
    }
    text = json.dumps(report, indent=2)
    print(text)
    if a.out:
        with open(a.out, "w") as f:
            f.write(text + "\n")
    return 0 if not lost and fivexx == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
