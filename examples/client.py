#!/usr/bin/env python3
"""A minimal rigserve client (standard library only): upload a mesh, follow the job's
events, download the rigged GLB and the bone tree.

Usage:
    python3 examples/client.py MESH [--server http://127.0.0.1:8080] [--out DIR]
        [--key API_KEY] [--option NAME=VALUE ...]

Options are the query parameters of POST /v1/jobs (proto/openapi.yaml), for example
`--option category=humanoid --option animation=preview`. Writes DIR/<mesh>.rigged.glb
and DIR/<mesh>.skeleton.json and prints each event as it arrives; exits 1 when the job
fails. Connection and HTTP errors are one line on stderr (with the server's
`error_type`), exit status 2.
"""

import argparse
import http.client
import json
import os
import sys
import urllib.error
import urllib.parse
import urllib.request

CONTENT_TYPES = {
    ".glb": "model/gltf-binary",
    ".vrm": "model/gltf-binary",
    ".gltf": "model/gltf+json",
    ".obj": "model/obj",
}
TERMINAL = {"succeeded", "failed", "canceled", "expired"}


class Client:
    def __init__(self, server, key=None):
        self.server = server.rstrip("/")
        self.headers = {"Authorization": f"Bearer {key}"} if key else {}

    def request(self, method, path, body=None, headers=None):
        req = urllib.request.Request(
            self.server + path, data=body, method=method, headers={**self.headers, **(headers or {})}
        )
        try:
            return urllib.request.urlopen(req)
        except urllib.error.HTTPError as e:
            try:
                err = json.load(e)
                message = f"{err['error']} ({err['error_type']})"
            except (ValueError, KeyError):
                message = e.reason
            raise SystemExit(f"error: {method} {path}: HTTP {e.code}: {message}")
        except urllib.error.URLError as e:
            raise SystemExit(f"error: cannot reach rigserve at {self.server}: {e.reason}")

    def submit(self, path, options):
        try:
            with open(path, "rb") as f:
                body = f.read()
        except OSError as e:
            raise SystemExit(f"error: {path}: {e.strerror}")
        ext = os.path.splitext(path)[1].lower()
        query = urllib.parse.urlencode(options)
        headers = {"Content-Type": CONTENT_TYPES.get(ext, "application/octet-stream")}
        with self.request("POST", f"/v1/jobs?{query}", body, headers) as r:
            return json.load(r)

    def events(self, job_id):
        """Yields the job's events (dicts) until a terminal one, resuming after drops."""
        last = None
        while True:
            headers = {"Accept": "text/event-stream"}
            if last is not None:
                headers["Last-Event-ID"] = str(last)
            with self.request("GET", f"/v1/jobs/{job_id}/events", headers=headers) as r:
                data = []
                for raw in r:
                    line = raw.decode("utf-8").rstrip("\r\n")
                    if line.startswith("id:"):
                        last = line[3:].strip()
                    elif line.startswith("data:"):
                        data.append(line[5:].lstrip())
                    elif line == "" and data:
                        event = json.loads("\n".join(data))
                        data = []
                        yield event
                        if event["status"] in TERMINAL:
                            return
            # The server also ends streams when it shuts down: reconnect and resume.

    def download(self, path, dest):
        with self.request("GET", path) as r, open(dest, "wb") as f:
            f.write(r.read())


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("mesh")
    p.add_argument("--server", default=os.environ.get("RIGSERVE_URL", "http://127.0.0.1:8080"))
    p.add_argument("--out", default=".")
    p.add_argument("--key", default=os.environ.get("RIGSERVE_API_KEY"))
    p.add_argument("--option", action="append", default=[], metavar="NAME=VALUE")
    a = p.parse_args()
    options = []
    for o in a.option:
        name, sep, value = o.partition("=")
        if not sep:
            p.error(f"--option {o!r}: expected NAME=VALUE")
        options.append((name, value))

    client = Client(a.server, a.key)
    job = client.submit(a.mesh, options)
    print(f"job {job['id']}: {job['status']}", flush=True)
    final = None
    for ev in client.events(job["id"]):
        stage = f" {ev['stage']}" if ev.get("stage") else ""
        print(f"  {ev['status']}{stage} {ev['progress'] * 100:.0f}%", flush=True)
        final = ev
    if final["status"] != "succeeded":
        error = final.get("error") or {}
        print(f"job {final['status']}: {error.get('message', '')} ({error.get('code', '')})", file=sys.stderr)
        sys.exit(1)
    os.makedirs(a.out, exist_ok=True)
    stem = os.path.splitext(os.path.basename(a.mesh))[0]
    glb = os.path.join(a.out, f"{stem}.rigged.glb")
    tree = os.path.join(a.out, f"{stem}.skeleton.json")
    client.download(f"/v1/jobs/{job['id']}/result.glb", glb)
    client.download(f"/v1/jobs/{job['id']}/skeleton.json", tree)
    print(glb)
    print(tree)


if __name__ == "__main__":
    try:
        main()
    except SystemExit as e:
        # Our one-line errors exit 2; a failed job exits 1 (sys.exit(1) above).
        if isinstance(e.code, str):
            print(e.code, file=sys.stderr)
            sys.exit(2)
        raise
    except (OSError, http.client.HTTPException) as e:
        # A connection dropped mid-stream or mid-download.
        print(f"error: connection to rigserve lost: {e}", file=sys.stderr)
        sys.exit(2)
