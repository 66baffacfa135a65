"""Repair two things in Blitz3D (.b3d) files that stop assimp from reading them as the
game engine (Irrlicht / Minetest) does: duplicate node (bone) names, which assimp merges
into one bone, and brushes naming textures that do not exist ("Bad texture id"). The
geometry, weights and bind pose are left as they are."""
import struct

PARENT = {b"BB3D": 4, b"NODE": None, b"MESH": 4}  # bytes of own data before child chunks


def _chunks(data, off, end):
    while off + 8 <= end:
        tag = data[off:off + 4]
        ln = struct.unpack_from("<i", data, off + 4)[0]
        body_end = min(end, off + 8 + max(ln, 0))
        yield tag, off + 8, body_end
        off = body_end


def fix(data):
    """Returns (new bytes, list of changes)."""
    if data[:4] != b"BB3D":
        raise ValueError("not a B3D file")
    changes = []
    names = {}
    ntex = [0]

    def cstr(off):
        e = data.index(b"\x00", off)
        return data[off:e], e + 1

    def rebuild(tag, start, end):
        if tag == b"TEXS":
            off, n = start, 0
            while off < end:
                _, off = cstr(off)
                off += 28
                n += 1
            ntex[0] = n
            body = data[start:end]
        elif tag == b"BRUS":
            nt = struct.unpack_from("<i", data, start)[0]
            out = bytearray(data[start:start + 4])
            off = start + 4
            while off < end:
                name, o2 = cstr(off)
                out += data[off:o2] + data[o2:o2 + 28]
                o2 += 28
                for k in range(nt):
                    t = struct.unpack_from("<i", data, o2 + 4 * k)[0]
                    if t >= ntex[0] or t < -1:
                        changes.append(f"brush texture id {t} -> -1")
                        t = -1
                    out += struct.pack("<i", t)
                off = o2 + 4 * nt
            body = bytes(out)
        elif tag == b"NODE":
            name, off = cstr(start)
            key = name.decode("latin-1")
            if key in names:
                names[key] += 1
                new = f"{key}.dup{names[key]}"
                while new in names:
                    names[key] += 1
                    new = f"{key}.dup{names[key]}"
                names[new] = 0
                changes.append(f"node {key!r} renamed {new!r}")
                name = new.encode("latin-1")
            else:
                names[key] = 0
            head = name + b"\x00" + data[off:off + 40]
            body = head + b"".join(rebuild(t, s, e) for t, s, e in _chunks(data, off + 40, end))
        elif tag in PARENT:
            k = PARENT[tag]
            body = data[start:start + k] + b"".join(rebuild(t, s, e) for t, s, e in _chunks(data, start + k, end))
        else:
            body = data[start:end]
        return tag + struct.pack("<i", len(body)) + body

    ln = struct.unpack_from("<i", data, 4)[0]
    out = rebuild(b"BB3D", 8, min(len(data), 8 + ln))
    return out, changes
