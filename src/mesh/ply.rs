//! PLY (Stanford polygon files), ASCII and binary of either byte order: what TRELLIS and
//! other generators and scanners write. The `vertex` element's `x y z` and its colours
//! (`red green blue [alpha]`, kept as the output's `COLOR_0`), the `face` element's index
//! lists (polygons become fans); other elements and properties are read past. Counts from
//! the header are checked against the caps and the file's size before anything is
//! allocated.

use super::{Limits, Mesh, MeshError};
use glam::Vec3;

/// Headers are a few hundred bytes; this bounds the text scanned for `end_header`.
const MAX_HEADER: usize = 64 * 1024;
const MAX_CORNERS: usize = 4096;

pub fn is_ply(bytes: &[u8]) -> bool {
    bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n")
}

fn bad(msg: impl Into<String>) -> MeshError {
    MeshError::Ply(msg.into())
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    fn parse(s: &str) -> Result<Ty, MeshError> {
        Ok(match s {
            "char" | "int8" => Ty::I8,
            "uchar" | "uint8" => Ty::U8,
            "short" | "int16" => Ty::I16,
            "ushort" | "uint16" => Ty::U16,
            "int" | "int32" => Ty::I32,
            "uint" | "uint32" => Ty::U32,
            "float" | "float32" => Ty::F32,
            "double" | "float64" => Ty::F64,
            _ => return Err(bad(format!("unknown property type {s:?}"))),
        })
    }
    fn size(self) -> usize {
        match self {
            Ty::I8 | Ty::U8 => 1,
            Ty::I16 | Ty::U16 => 2,
            Ty::I32 | Ty::U32 | Ty::F32 => 4,
            Ty::F64 => 8,
        }
    }
    /// What a colour channel of this type reads as at full intensity.
    fn full(self) -> f64 {
        match self {
            Ty::U8 | Ty::I8 => 255.0,
            Ty::U16 | Ty::I16 => 65535.0,
            Ty::U32 | Ty::I32 => u32::MAX as f64,
            Ty::F32 | Ty::F64 => 1.0,
        }
    }
}

#[derive(Debug)]
enum Prop {
    Scalar(String, Ty),
    List(String, Ty, Ty),
}

#[derive(Debug)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Prop>,
}

#[derive(Clone, Copy, PartialEq)]
enum Encoding {
    Ascii,
    Little,
    Big,
}

/// The body, read one value at a time.
enum Body<'a> {
    Ascii(std::str::SplitAsciiWhitespace<'a>),
    Binary {
        data: &'a [u8],
        pos: usize,
        big: bool,
    },
}

impl Body<'_> {
    fn read(&mut self, ty: Ty) -> Result<f64, MeshError> {
        match self {
            Body::Ascii(it) => {
                let t = it
                    .next()
                    .ok_or_else(|| bad("the data ends before the header's counts"))?;
                t.parse::<f64>()
                    .map_err(|_| bad(format!("{t:?} is not a number")))
            }
            Body::Binary { data, pos, big } => {
                let n = ty.size();
                let b = data
                    .get(*pos..*pos + n)
                    .ok_or_else(|| bad("the data ends before the header's counts"))?;
                *pos += n;
                let mut a = [0u8; 8];
                a[..n].copy_from_slice(b);
                if *big {
                    a[..n].reverse();
                }
                Ok(match ty {
                    Ty::I8 => a[0] as i8 as f64,
                    Ty::U8 => a[0] as f64,
                    Ty::I16 => i16::from_le_bytes([a[0], a[1]]) as f64,
                    Ty::U16 => u16::from_le_bytes([a[0], a[1]]) as f64,
                    Ty::I32 => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
                    Ty::U32 => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
                    Ty::F32 => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
                    Ty::F64 => f64::from_le_bytes(a),
                })
            }
        }
    }
}

fn header(bytes: &[u8]) -> Result<(Encoding, Vec<Element>, usize), MeshError> {
    let window = &bytes[..bytes.len().min(MAX_HEADER)];
    let end = window
        .windows(10)
        .position(|w| w == b"end_header")
        .ok_or_else(|| bad("no end_header in the first 64 KiB"))?;
    let mut body = end + 10;
    // The header's last line ends in \n or \r\n.
    if bytes.get(body) == Some(&b'\r') {
        body += 1;
    }
    if bytes.get(body) == Some(&b'\n') {
        body += 1;
    }
    let text = std::str::from_utf8(&bytes[..end]).map_err(|_| bad("the header is not text"))?;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in text.lines().skip(1) {
        let w: Vec<&str> = line.split_ascii_whitespace().collect();
        match w.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", f, _version] => {
                encoding = Some(match *f {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::Little,
                    "binary_big_endian" => Encoding::Big,
                    _ => return Err(bad(format!("unknown format {f:?}"))),
                })
            }
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count
                    .parse()
                    .map_err(|_| bad(format!("element count {count:?}")))?,
                props: Vec::new(),
            }),
            ["property", "list", c, i, name] => elements
                .last_mut()
                .ok_or_else(|| bad("a property before any element"))?
                .props
                .push(Prop::List(name.to_string(), Ty::parse(c)?, Ty::parse(i)?)),
            ["property", ty, name] => elements
                .last_mut()
                .ok_or_else(|| bad("a property before any element"))?
                .props
                .push(Prop::Scalar(name.to_string(), Ty::parse(ty)?)),
            _ => return Err(bad(format!("header line {line:?}"))),
        }
    }
    Ok((
        encoding.ok_or_else(|| bad("no format line"))?,
        elements,
        body,
    ))
}

/// The loaded mesh and, when the vertices have colours, one RGBA per mesh vertex.
pub fn load(bytes: &[u8], limits: &Limits) -> Result<(Mesh, Vec<[f32; 4]>), MeshError> {
    let (encoding, elements, start) = header(bytes)?;
    let rest = &bytes[start..];
    let mut body = match encoding {
        Encoding::Ascii => Body::Ascii(
            std::str::from_utf8(rest)
                .map_err(|_| bad("an ASCII body that is not text"))?
                .split_ascii_whitespace(),
        ),
        e => Body::Binary {
            data: rest,
            pos: 0,
            big: e == Encoding::Big,
        },
    };
    let mut positions: Vec<Vec3> = Vec::new();
    let mut colors: Vec<[f32; 4]> = Vec::new();
    let mut faces: Vec<[u32; 3]> = Vec::new();
    let mut seen_vertex = false;
    for el in &elements {
        // The caps first: they name the fault better than the size check below.
        if el.name == "vertex" && el.count > limits.max_vertices {
            return Err(MeshError::TooManyVertices {
                count: el.count,
                cap: limits.max_vertices,
            });
        }
        if el.name == "face" && el.count > limits.max_triangles {
            return Err(MeshError::TooManyTriangles {
                count: el.count,
                cap: limits.max_triangles,
            });
        }
        // Every record holds at least a byte (binary) or a character (ASCII) per
        // property, so a count the file cannot hold is refused before allocating.
        let min_record = el.props.len().max(1) as u64;
        if el.count.saturating_mul(min_record) > rest.len() as u64 {
            return Err(bad(format!(
                "{} {} records cannot fit in {} bytes",
                el.count,
                el.name,
                rest.len()
            )));
        }
        match el.name.as_str() {
            "vertex" if !seen_vertex => {
                seen_vertex = true;
                read_vertices(&mut body, el, &mut positions, &mut colors)?;
            }
            "face" => {
                read_faces(&mut body, el, positions.len(), limits, &mut faces)?;
            }
            _ => skip(&mut body, el)?,
        }
    }
    if faces.is_empty() {
        return Err(MeshError::EmptyScene);
    }
    let (mesh, remap) = super::plain::from_faces(&positions, faces);
    let colors = if colors.is_empty() {
        colors
    } else {
        super::plain::follow(&colors, &remap, mesh.positions.len())
    };
    Ok((mesh, colors))
}

fn read_vertices(
    body: &mut Body,
    el: &Element,
    positions: &mut Vec<Vec3>,
    colors: &mut Vec<[f32; 4]>,
) -> Result<(), MeshError> {
    let slot = |name: &str| {
        el.props
            .iter()
            .position(|p| matches!(p, Prop::Scalar(n, _) if n == name))
    };
    let (Some(x), Some(y), Some(z)) = (slot("x"), slot("y"), slot("z")) else {
        return Err(bad("the vertex element has no x, y and z"));
    };
    let rgb = [
        slot("red").or(slot("r")),
        slot("green").or(slot("g")),
        slot("blue").or(slot("b")),
    ];
    let alpha = slot("alpha").or(slot("a"));
    let coloured = rgb.iter().all(Option::is_some);
    positions.reserve(el.count as usize);
    if coloured {
        colors.reserve(el.count as usize);
    }
    let mut values = vec![0f64; el.props.len()];
    let scale: Vec<f64> = el
        .props
        .iter()
        .map(|p| match p {
            Prop::Scalar(_, ty) => ty.full(),
            Prop::List(..) => 1.0,
        })
        .collect();
    for _ in 0..el.count {
        for (k, p) in el.props.iter().enumerate() {
            match p {
                Prop::Scalar(_, ty) => values[k] = body.read(*ty)?,
                Prop::List(_, c, i) => {
                    let n = body.read(*c)?;
                    for _ in 0..list_len(n)? {
                        body.read(*i)?;
                    }
                }
            }
        }
        let v = Vec3::new(values[x] as f32, values[y] as f32, values[z] as f32);
        if !v.is_finite() {
            return Err(MeshError::NonFinite);
        }
        positions.push(v);
        if coloured {
            let ch =
                |s: Option<usize>| s.map_or(1.0, |k| (values[k] / scale[k]).clamp(0.0, 1.0) as f32);
            colors.push([ch(rgb[0]), ch(rgb[1]), ch(rgb[2]), ch(alpha)]);
        }
    }
    Ok(())
}

fn read_faces(
    body: &mut Body,
    el: &Element,
    vertices: usize,
    limits: &Limits,
    faces: &mut Vec<[u32; 3]>,
) -> Result<(), MeshError> {
    let list = el
        .props
        .iter()
        .position(
            |p| matches!(p, Prop::List(n, ..) if n == "vertex_indices" || n == "vertex_index"),
        )
        .ok_or_else(|| bad("the face element has no vertex_indices list"))?;
    let mut corners: Vec<u32> = Vec::new();
    for _ in 0..el.count {
        for (k, p) in el.props.iter().enumerate() {
            match p {
                Prop::Scalar(_, ty) => {
                    body.read(*ty)?;
                }
                Prop::List(_, c, i) => {
                    let n = list_len(body.read(*c)?)?;
                    if k == list && n > MAX_CORNERS {
                        return Err(bad(format!("a face with {n} corners")));
                    }
                    corners.clear();
                    for _ in 0..n {
                        let v = body.read(*i)?;
                        if k == list {
                            if !(v >= 0.0 && v < vertices as f64 && v.fract() == 0.0) {
                                return Err(MeshError::IndexOutOfRange {
                                    what: "PLY vertex",
                                    index: v.max(0.0) as u64,
                                });
                            }
                            corners.push(v as u32);
                        }
                    }
                    if k != list {
                        continue;
                    }
                    if n < 3 {
                        return Err(bad(format!("a face with {n} corners")));
                    }
                    for w in 2..n {
                        if faces.len() as u64 >= limits.max_triangles {
                            return Err(MeshError::TooManyTriangles {
                                count: faces.len() as u64 + 1,
                                cap: limits.max_triangles,
                            });
                        }
                        faces.push([corners[0], corners[w - 1], corners[w]]);
                    }
                }
            }
        }
    }
    Ok(())
}

fn skip(body: &mut Body, el: &Element) -> Result<(), MeshError> {
    for _ in 0..el.count {
        for p in &el.props {
            match p {
                Prop::Scalar(_, ty) => {
                    body.read(*ty)?;
                }
                Prop::List(_, c, i) => {
                    for _ in 0..list_len(body.read(*c)?)? {
                        body.read(*i)?;
                    }
                }
            }
        }
    }
    Ok(())
}

fn list_len(n: f64) -> Result<usize, MeshError> {
    if n >= 0.0 && n.fract() == 0.0 && n <= u32::MAX as f64 {
        Ok(n as usize)
    } else {
        Err(bad(format!("list length {n}")))
    }
}
