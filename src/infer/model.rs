//! The encoder and decoder sessions of a `skeleton-v2` model
//! (`training/skeleton/ONNX_CONTRACT.md`): loading, contract validation, and the three
//! calls a decoder loop needs (encode, prefill, one cached step).

use super::kv::KvCache;
use super::ragged::RaggedKv;
use super::{InferError, Runtime};
use crate::rig::tokenizer::{ALT, PAD};
use ndarray::{Array2, Array3, Array4, ArrayView2, ArrayView4, Axis, Ix3, Ix4};
use ort::session::builder::GraphOptimizationLevel;
use ort::session::{Session, SessionInputValue};
use ort::value::{Outlet, Tensor, TensorElementType, TensorRef, ValueType};
use std::borrow::Cow;
use std::path::{Path, PathBuf};

/// The only contract this crate speaks. v2's decoder returns only the new positions'
/// keys and values, so the cache stays in place ([`KvCache`]); a `skeleton-v1` file is
/// refused with a contract error naming both (re-export it from its weights:
/// `training/skeleton/init_from_onnx.py`).
pub const CONTRACT: &str = "skeleton-v2";

/// Which exported weights to load: `encoder{suffix}.onnx` / `decoder{suffix}.onnx`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Variant {
    #[default]
    Fp32,
    Fp16,
    Int8,
}

impl Variant {
    fn suffix(self) -> &'static str {
        match self {
            Variant::Fp32 => "",
            Variant::Fp16 => ".fp16",
            Variant::Int8 => ".int8",
        }
    }
}

impl std::str::FromStr for Variant {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "fp32" | "f32" => Ok(Variant::Fp32),
            "fp16" | "f16" => Ok(Variant::Fp16),
            "int8" | "i8" => Ok(Variant::Int8),
            _ => Err(format!("unknown model variant {s:?} (fp32, fp16, int8)")),
        }
    }
}

/// Paths of the ONNX files.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ModelFiles {
    pub encoder: PathBuf,
    pub decoder: PathBuf,
    /// The ragged decode step (ONNX_CONTRACT.md, "Decode step"); optional: without it
    /// decode steps run `decoder` over a [`KvCache`].
    pub step: PathBuf,
}

impl ModelFiles {
    /// The files in `dir` as `training/skeleton/export.py` names them. `dir` may be the
    /// export folder itself or a models root holding it as `skeleton/`; the first that has
    /// an encoder wins (when neither does, the error names `dir` itself).
    pub fn in_dir(dir: &Path, variant: Variant) -> ModelFiles {
        let at = |d: &Path| ModelFiles {
            encoder: d.join(format!("encoder{}.onnx", variant.suffix())),
            decoder: d.join(format!("decoder{}.onnx", variant.suffix())),
            step: d.join(format!("decoder_step{}.onnx", variant.suffix())),
        };
        let direct = at(dir);
        if direct.encoder.is_file() {
            return direct;
        }
        let nested = at(&dir.join("skeleton"));
        if nested.encoder.is_file() {
            nested
        } else {
            direct
        }
    }
}

/// Session settings. One intra-op thread by default: the server runs one inference
/// thread and scales by batching, not by fanning one call out over cores.
#[derive(Clone, Debug)]
pub struct SessionConfig {
    pub intra_threads: usize,
}

impl Default for SessionConfig {
    fn default() -> Self {
        SessionConfig { intra_threads: 1 }
    }
}

/// The model's dimensions, from the `custom_metadata_map` of both files.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct ModelInfo {
    pub d_model: usize,
    /// L: rows of the encoder's prefix, and the first token position.
    pub n_latents: usize,
    pub n_layers: usize,
    pub n_heads: usize,
    pub head_dim: usize,
    /// Output width of the decoder; may differ from the tokenizer's vocabulary (ids the
    /// model lacks are never sampled, ids past the tokenizer's are masked).
    pub vocab_size: usize,
    pub max_positions: usize,
    /// Longest sequence, prompt included.
    pub max_tokens: usize,
    pub exporter: Option<String>,
}

/// `points` (B, N, 6) → prefix (B, L, d), checked.
fn run_encoder(
    session: &mut Session,
    info: &ModelInfo,
    points: &Array3<f32>,
) -> Result<Array3<f32>, InferError> {
    let (b, n, c) = points.dim();
    if b == 0 || n == 0 || c != 6 {
        return Err(InferError::InvalidRequest(format!(
            "encoder input must be (B ≥ 1, N ≥ 1, 6), got ({b}, {n}, {c})"
        )));
    }
    let input = TensorRef::from_array_view(points.view())
        .map_err(|e| InferError::run("encoder input", e))?;
    let out = session
        .run(ort::inputs!["points" => input])
        .map_err(|e| InferError::run("encoder", e))?;
    let prefix = out["prefix"]
        .try_extract_array::<f32>()
        .map_err(|e| InferError::run("encoder output", e))?;
    let want = [b, info.n_latents, info.d_model];
    if prefix.shape() != want {
        return Err(InferError::OutputShape {
            name: "prefix".into(),
            got: prefix.shape().to_vec(),
            expected: format!("{want:?}"),
        });
    }
    Ok(prefix
        .into_dimensionality::<Ix3>()
        .expect("shape checked")
        .to_owned())
}

/// The encoder session, on its own so the backend can run it on the submitting threads
/// ([`SkeletonModel::take_encoder`]).
pub struct PointEncoder {
    session: Session,
    info: ModelInfo,
}

impl PointEncoder {
    pub fn encode(&mut self, points: &Array3<f32>) -> Result<Array3<f32>, InferError> {
        run_encoder(&mut self.session, &self.info, points)
    }
}

/// A loaded `skeleton-v2` model. `run` needs `&mut`, so one thread owns it (see
/// [`super::Backend`]).
pub struct SkeletonModel {
    /// `None` once handed out by [`SkeletonModel::take_encoder`].
    encoder: Option<PointEncoder>,
    decoder: Session,
    /// `decoder_step.onnx` when the folder has one.
    step: Option<Session>,
    /// Its attention takes a cache of more rows than the batch (rigserve's op; metadata
    /// `rigserve.attention`), so ragged caches keep spare slots.
    step_spare_slots: bool,
    /// Its cache is half precision (`float16` past and present).
    step_half: bool,
    info: ModelInfo,
    files: ModelFiles,
    past_names: Vec<String>,
    new_names: Vec<String>,
    present_names: Vec<String>,
}

impl std::fmt::Debug for SkeletonModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SkeletonModel")
            .field("files", &self.files)
            .field("info", &self.info)
            .finish()
    }
}

pub(super) fn open_session(
    rt: &Runtime,
    path: &Path,
    cfg: &SessionConfig,
) -> Result<Session, InferError> {
    open_session_with(rt, path, cfg, false)
}

/// `custom_ops`: register rigserve's operator domain (`ai.rigserve`), which the decode
/// step graph uses for its attention.
fn open_session_with(
    rt: &Runtime,
    path: &Path,
    cfg: &SessionConfig,
    custom_ops: bool,
) -> Result<Session, InferError> {
    if !path.is_file() {
        return Err(InferError::ModelNotFound(path.to_path_buf()));
    }
    let load = |m: String| InferError::ModelLoad {
        path: path.to_path_buf(),
        message: m,
    };
    // ONNX Runtime adds a custom domain to a process-wide schema map while it builds the
    // session, and two sessions doing so at once fail with "domain already exist": so
    // sessions with rigserve's operators are built one at a time.
    static CUSTOM_OPS: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _one_at_a_time = custom_ops.then(|| CUSTOM_OPS.lock().unwrap_or_else(|e| e.into_inner()));
    let mut builder = Session::builder(rt.env()).map_err(|e| load(e.to_string()))?;
    if custom_ops {
        let ops = super::attention_op::operators().map_err(|e| load(e.to_string()))?;
        builder = builder
            .with_operators(ops)
            .map_err(|e| load(e.to_string()))?;
    }
    builder
        .with_intra_threads(cfg.intra_threads.max(1))
        .map_err(|e| load(e.to_string()))?
        .with_inter_threads(1)
        .map_err(|e| load(e.to_string()))?
        .with_optimization_level(GraphOptimizationLevel::Level3)
        .map_err(|e| load(e.to_string()))?
        .commit_from_file(path)
        .map_err(|e| load(e.to_string()))
}

/// A dimension as the contract states it.
#[derive(Clone, Copy)]
pub(super) enum Dim {
    /// Must be dynamic: it changes from call to call (batch, sequence lengths).
    Dynamic,
    /// Must be this size, or dynamic.
    Is(usize),
}

pub(super) struct Expect<'a> {
    pub(super) name: &'a str,
    pub(super) ty: TensorElementType,
    pub(super) dims: &'a [Dim],
}

/// One tensor of `ty` per name, all of shape `dims` (the cache inputs and outputs).
fn cache_outlets<'a>(
    names: &'a [String],
    dims: &'a [Dim],
    ty: TensorElementType,
) -> impl Iterator<Item = Expect<'a>> {
    names.iter().map(move |n| Expect { name: n, ty, dims })
}

/// `decoder_step.onnx`, opened and checked.
struct Step {
    session: Session,
    /// Its attention takes a cache of more rows than the batch (rigserve's op).
    spare_slots: bool,
    /// Its cache tensors are `float16`.
    half: bool,
}

pub(super) fn check_outlets(
    path: &Path,
    what: &str,
    got: &[Outlet],
    want: &[Expect],
) -> Result<(), InferError> {
    let bad = |problem: String| InferError::Contract {
        path: path.to_path_buf(),
        problem,
    };
    let mut got_names: Vec<&str> = got.iter().map(|o| o.name()).collect();
    let mut want_names: Vec<&str> = want.iter().map(|e| e.name).collect();
    got_names.sort_unstable();
    want_names.sort_unstable();
    if got_names != want_names {
        return Err(bad(format!(
            "{what} are {:?}, expected {:?}",
            got.iter().map(|o| o.name()).collect::<Vec<_>>(),
            want.iter().map(|e| e.name).collect::<Vec<_>>()
        )));
    }
    for e in want {
        let o = got
            .iter()
            .find(|o| o.name() == e.name)
            .expect("names checked");
        let ValueType::Tensor { ty, shape, .. } = o.dtype() else {
            return Err(bad(format!("{} is not a tensor", e.name)));
        };
        if *ty != e.ty {
            return Err(bad(format!(
                "{} has element type {ty:?}, expected {:?}",
                e.name, e.ty
            )));
        }
        if shape.len() != e.dims.len() {
            return Err(bad(format!(
                "{} has rank {}, expected {}",
                e.name,
                shape.len(),
                e.dims.len()
            )));
        }
        for (axis, (&g, d)) in shape.iter().zip(e.dims).enumerate() {
            let ok = match *d {
                Dim::Dynamic => g < 0,
                Dim::Is(v) => g < 0 || g as usize == v,
            };
            if !ok {
                let want = match *d {
                    Dim::Dynamic => "dynamic".to_string(),
                    Dim::Is(v) => v.to_string(),
                };
                return Err(bad(format!(
                    "{} axis {axis} is {g}, expected {want}",
                    e.name
                )));
            }
        }
    }
    Ok(())
}

fn read_metadata(session: &Session, path: &Path, part: &str) -> Result<ModelInfo, InferError> {
    let bad = |problem: String| InferError::Contract {
        path: path.to_path_buf(),
        problem,
    };
    let meta = session
        .metadata()
        .map_err(|e| bad(format!("no metadata: {e}")))?;
    let get = |k: &str| meta.custom(k);
    match get("rigserve.contract") {
        Some(c) if c == CONTRACT => {}
        Some(c) => {
            return Err(bad(format!(
                "rigserve.contract is {c:?}, expected {CONTRACT:?}"
            )))
        }
        None => return Err(bad("metadata rigserve.contract is missing".into())),
    }
    match get("rigserve.part") {
        Some(p) if p == part => {}
        other => {
            return Err(bad(format!(
                "rigserve.part is {other:?}, expected {part:?} (files swapped?)"
            )))
        }
    }
    let num = |k: &str| -> Result<usize, InferError> {
        let v = get(k).ok_or_else(|| bad(format!("metadata {k} is missing")))?;
        v.trim()
            .parse::<usize>()
            .ok()
            .filter(|&n| n > 0)
            .ok_or_else(|| bad(format!("metadata {k} = {v:?} is not a positive integer")))
    };
    let info = ModelInfo {
        d_model: num("d_model")?,
        n_latents: num("n_latents")?,
        n_layers: num("n_layers")?,
        n_heads: num("n_heads")?,
        head_dim: num("head_dim")?,
        vocab_size: num("vocab_size")?,
        max_positions: num("max_positions")?,
        max_tokens: num("max_tokens")?,
        exporter: get("rigserve.exporter"),
    };
    if info.n_heads * info.head_dim != info.d_model {
        return Err(bad(format!(
            "n_heads {} × head_dim {} != d_model {}",
            info.n_heads, info.head_dim, info.d_model
        )));
    }
    if info.max_positions < info.n_latents + info.max_tokens {
        return Err(bad(format!(
            "max_positions {} < n_latents {} + max_tokens {}",
            info.max_positions, info.n_latents, info.max_tokens
        )));
    }
    // Class tokens are the prompt; a model without them cannot be driven.
    if info.vocab_size < ALT as usize {
        return Err(bad(format!(
            "vocab_size {} does not reach the class tokens (needs at least {ALT})",
            info.vocab_size
        )));
    }
    if info.max_tokens < 4 {
        return Err(bad(format!(
            "max_tokens {} leaves no room for a bone",
            info.max_tokens
        )));
    }
    Ok(info)
}

/// Opens `decoder_step.onnx` and checks it against the decoder it steps for: same
/// contract and dimensions, the ragged inputs and outputs of ONNX_CONTRACT.md.
fn load_step(
    rt: &Runtime,
    files: &ModelFiles,
    cfg: &SessionConfig,
    info: &ModelInfo,
    past_names: &[String],
    present_names: &[String],
) -> Result<Step, InferError> {
    use Dim::*;
    use TensorElementType::{Float16, Float32, Int32, Int64};
    let path = &files.step;
    let step = open_session_with(rt, path, cfg, true)?;
    let got = read_metadata(&step, path, "decoder_step")?;
    let spare_slots = step
        .metadata()
        .ok()
        .and_then(|m| m.custom("rigserve.attention"))
        .is_some_and(|a| a == "rigserve");
    // The cache's number type is the graph's: half precision needs rigserve's op (the
    // other ops keep the cache in the type of q, k and v).
    let cache_ty = step
        .inputs()
        .iter()
        .find(|o| past_names.first().is_some_and(|n| o.name() == n))
        .and_then(|o| match o.dtype() {
            ValueType::Tensor { ty, .. } => Some(*ty),
            _ => None,
        })
        .unwrap_or(Float32);
    if cache_ty == Float16 && !spare_slots {
        return Err(InferError::Contract {
            path: path.clone(),
            problem: "a float16 cache needs rigserve.attention = rigserve".into(),
        });
    }
    let cache_ty = if cache_ty == Float16 {
        Float16
    } else {
        Float32
    };
    let same = |a: &ModelInfo| {
        (
            a.d_model,
            a.n_latents,
            a.n_layers,
            a.n_heads,
            a.head_dim,
            a.vocab_size,
            a.max_positions,
        )
    };
    if same(&got) != same(info) {
        return Err(InferError::Contract {
            path: path.clone(),
            problem: format!(
                "dimensions {:?} do not match the decoder's {:?}",
                same(&got),
                same(info)
            ),
        });
    }
    let kv_dims = [Dynamic, Is(info.n_heads), Dynamic, Is(info.head_dim)];
    let mut ins = vec![
        Expect {
            name: "input_ids",
            ty: Int64,
            dims: &[Dynamic, Is(1)],
        },
        Expect {
            name: "position_ids",
            ty: Int64,
            dims: &[Dynamic, Is(1)],
        },
        Expect {
            name: "seqlens_k",
            ty: Int32,
            dims: &[Dynamic],
        },
        Expect {
            name: "total_sequence_length",
            ty: Int32,
            dims: &[],
        },
    ];
    ins.extend(cache_outlets(past_names, &kv_dims, cache_ty));
    check_outlets(path, "decode step inputs", step.inputs(), &ins)?;
    let logits_dims = [Dynamic, Is(1), Is(info.vocab_size)];
    let mut outs = vec![Expect {
        name: "logits",
        ty: Float32,
        dims: &logits_dims,
    }];
    outs.extend(cache_outlets(present_names, &kv_dims, cache_ty));
    check_outlets(path, "decode step outputs", step.outputs(), &outs)?;
    Ok(Step {
        session: step,
        spare_slots,
        half: cache_ty == Float16,
    })
}

impl SkeletonModel {
    /// Opens both files and checks them against the contract: metadata (contract, part,
    /// consistent dimensions, the encoder agreeing with the decoder) and every input and
    /// output (names, element types, ranks, static sizes). Any mismatch is an
    /// [`InferError::Contract`] naming the file.
    pub fn load(rt: &Runtime, files: &ModelFiles, cfg: &SessionConfig) -> Result<Self, InferError> {
        let encoder = open_session(rt, &files.encoder, cfg)?;
        let decoder = open_session(rt, &files.decoder, cfg)?;
        let enc_info = read_metadata(&encoder, &files.encoder, "encoder")?;
        let info = read_metadata(&decoder, &files.decoder, "decoder")?;
        if (enc_info.d_model, enc_info.n_latents) != (info.d_model, info.n_latents) {
            return Err(InferError::Contract {
                path: files.encoder.clone(),
                problem: format!(
                    "encoder (d_model {}, n_latents {}) does not match decoder (d_model {}, n_latents {})",
                    enc_info.d_model, enc_info.n_latents, info.d_model, info.n_latents
                ),
            });
        }
        use Dim::*;
        use TensorElementType::{Float32, Int64};
        check_outlets(
            &files.encoder,
            "encoder inputs",
            encoder.inputs(),
            &[Expect {
                name: "points",
                ty: Float32,
                dims: &[Dynamic, Dynamic, Is(6)],
            }],
        )?;
        check_outlets(
            &files.encoder,
            "encoder outputs",
            encoder.outputs(),
            &[Expect {
                name: "prefix",
                ty: Float32,
                dims: &[Dynamic, Is(info.n_latents), Is(info.d_model)],
            }],
        )?;
        let past_names: Vec<String> = (0..info.n_layers)
            .flat_map(|i| {
                [
                    format!("past_key_values.{i}.key"),
                    format!("past_key_values.{i}.value"),
                ]
            })
            .collect();
        let new_names: Vec<String> = (0..info.n_layers)
            .flat_map(|i| {
                [
                    format!("new_key_values.{i}.key"),
                    format!("new_key_values.{i}.value"),
                ]
            })
            .collect();
        let kv_dims = [Dynamic, Is(info.n_heads), Dynamic, Is(info.head_dim)];
        let prefix_dims = [Dynamic, Dynamic, Is(info.d_model)];
        let logits_dims = [Dynamic, Dynamic, Is(info.vocab_size)];
        let mut ins = vec![
            Expect {
                name: "input_ids",
                ty: Int64,
                dims: &[Dynamic, Dynamic],
            },
            Expect {
                name: "prefix",
                ty: Float32,
                dims: &prefix_dims,
            },
            Expect {
                name: "position_ids",
                ty: Int64,
                dims: &[Dynamic, Dynamic],
            },
            Expect {
                name: "attention_mask",
                ty: Int64,
                dims: &[Dynamic, Dynamic],
            },
        ];
        ins.extend(cache_outlets(&past_names, &kv_dims, Float32));
        check_outlets(&files.decoder, "decoder inputs", decoder.inputs(), &ins)?;
        let mut outs = vec![Expect {
            name: "logits",
            ty: Float32,
            dims: &logits_dims,
        }];
        outs.extend(cache_outlets(&new_names, &kv_dims, Float32));
        check_outlets(&files.decoder, "decoder outputs", decoder.outputs(), &outs)?;
        let present_names: Vec<String> = (0..info.n_layers)
            .flat_map(|i| [format!("present.{i}.key"), format!("present.{i}.value")])
            .collect();
        let step = if files.step.is_file() {
            Some(load_step(
                rt,
                files,
                cfg,
                &info,
                &past_names,
                &present_names,
            )?)
        } else {
            None
        };
        let has_step = step.is_some();
        let step_spare_slots = step.as_ref().is_some_and(|s| s.spare_slots);
        let step_half = step.as_ref().is_some_and(|s| s.half);
        let step = step.map(|s| s.session);
        let mut model = SkeletonModel {
            encoder: Some(PointEncoder {
                session: encoder,
                info: info.clone(),
            }),
            decoder,
            step,
            step_spare_slots,
            step_half,
            info,
            files: files.clone(),
            past_names,
            new_names,
            present_names,
        };
        if has_step {
            model.check_step_agrees()?;
        }
        Ok(model)
    }

    /// Whether decode steps can run ragged ([`SkeletonModel::decode_step_ragged`]).
    pub fn has_step(&self) -> bool {
        self.step.is_some()
    }

    pub fn info(&self) -> &ModelInfo {
        &self.info
    }

    pub fn files(&self) -> &ModelFiles {
        &self.files
    }

    /// `points` (B, N, 6) → prefix (B, L, d).
    pub fn encode(&mut self, points: &Array3<f32>) -> Result<Array3<f32>, InferError> {
        self.encoder
            .as_mut()
            .ok_or_else(|| InferError::run("encoder", "the encoder was handed to the backend"))?
            .encode(points)
    }

    /// Hands out the encoder session, for callers that encode on their own thread (the
    /// backend's submitters, so the inference thread only prefills and decodes).
    pub fn take_encoder(&mut self) -> Result<PointEncoder, InferError> {
        self.encoder
            .take()
            .ok_or_else(|| InferError::run("encoder", "the encoder was already handed out"))
    }

    /// First decoder call for a batch: `prefixes` (B, L, d) from the encoder, `prompts`
    /// left-padded with `<pad>` to the longest. Returns the next-token logits (B, V) and
    /// the cache to continue from.
    pub fn prefill(
        &mut self,
        prefixes: &Array3<f32>,
        prompts: &[&[u32]],
    ) -> Result<(Array2<f32>, KvCache), InferError> {
        let info = &self.info;
        let (b, l, d) = prefixes.dim();
        if b != prompts.len() || l != info.n_latents || d != info.d_model || b == 0 {
            return Err(InferError::InvalidRequest(format!(
                "prefill of {} prompts with a prefix of shape ({b}, {l}, {d})",
                prompts.len()
            )));
        }
        let t0 = prompts.iter().map(|p| p.len()).max().unwrap_or(0);
        if t0 == 0 || t0 > info.max_tokens {
            return Err(InferError::InvalidRequest(format!(
                "prompt lengths must be in 1..={}, longest is {t0}",
                info.max_tokens
            )));
        }
        let mut ids = Array2::<i64>::from_elem((b, t0), PAD as i64);
        let mut pos = Array2::<i64>::from_elem((b, l + t0), l as i64);
        let mut mask = Array2::<i64>::zeros((b, l + t0));
        let mut next_pos = Vec::with_capacity(b);
        for (j, p) in prompts.iter().enumerate() {
            let pad = t0 - p.len();
            for (k, &t) in p.iter().enumerate() {
                ids[[j, pad + k]] = t as i64;
                pos[[j, l + pad + k]] = (l + k) as i64;
                mask[[j, l + pad + k]] = 1;
            }
            for k in 0..l {
                pos[[j, k]] = k as i64;
                mask[[j, k]] = 1;
            }
            next_pos.push((l + p.len()) as i64);
        }
        let empty_past = Array4::<f32>::zeros((b, info.n_heads, 0, info.head_dim));
        let prefix_in = TensorRef::from_array_view(prefixes.view())
            .map_err(|e| InferError::run("prefill input", e))?;
        let (logits, cache) = self.run_decoder(
            ids,
            prefix_in.into(),
            pos,
            mask.view(),
            |_| Ok(TensorRef::from_array_view(empty_past.view())?.into()),
            usize::MAX,
            |new| KvCache::from_new(new, mask.clone(), next_pos),
        )?;
        Ok((last_row(logits), cache))
    }

    /// One token per row, and every row still inside the position table.
    fn check_step(&self, tokens: usize, rows: usize, next: &[i64]) -> Result<(), InferError> {
        if tokens != rows || rows == 0 {
            return Err(InferError::InvalidRequest(format!(
                "decode step with {tokens} tokens for a cache of {rows} rows"
            )));
        }
        if next.iter().any(|&p| p as usize >= self.info.max_positions) {
            return Err(InferError::InvalidRequest(format!(
                "a sequence would pass the model's {} positions",
                self.info.max_positions
            )));
        }
        Ok(())
    }

    /// One cached step: appends `tokens` (one per cache row) and returns the next-token
    /// logits (B, V). On error the cache is left as it was.
    pub fn decode_step(
        &mut self,
        tokens: &[u32],
        cache: &mut KvCache,
    ) -> Result<Array2<f32>, InferError> {
        let b = cache.batch();
        self.check_step(tokens.len(), b, cache.next_positions())?;
        let ids = Array2::from_shape_vec((b, 1), tokens.iter().map(|&t| t as i64).collect())
            .expect("b×1");
        let pos = Array2::from_shape_vec((b, 1), cache.next_positions().to_vec()).expect("b×1");
        // The whole buffer is the past, unwritten columns masked: the decoder reads the
        // cache where it lies, and only the new column is copied back (`KvCache::push`).
        let mask = cache.step_mask();
        let empty_prefix = Array3::<f32>::zeros((b, 0, self.info.d_model));
        let prefix_in = TensorRef::from_array_view(empty_prefix.view())
            .map_err(|e| InferError::run("decode input", e))?;
        let (logits, new) = {
            let past = &*cache;
            self.run_decoder(
                ids,
                prefix_in.into(),
                pos,
                mask.view(),
                |i| Ok(TensorRef::from_array_view(past.tensor(i))?.into()),
                usize::MAX,
                |new| Ok(new.iter().map(|a| a.to_owned()).collect::<Vec<_>>()),
            )?
        };
        let views: Vec<ArrayView4<f32>> = new.iter().map(|a| a.view()).collect();
        cache.push(&views)?;
        Ok(last_row(logits))
    }

    /// One ragged step (`decoder_step.onnx`): appends `tokens` (one per live row) and
    /// returns the next-token logits of the live rows (B, V). The op writes the new keys and
    /// values into the cache's own tensors, bound as both past and present. On error the
    /// cache's lengths are unchanged (a column past every row's length may have been
    /// written, which no row reads).
    pub fn decode_step_ragged(
        &mut self,
        tokens: &[u32],
        cache: &mut RaggedKv,
    ) -> Result<Array2<f32>, InferError> {
        let b = cache.batch();
        self.check_step(tokens.len(), b, cache.next_positions())?;
        let Some(step) = self.step.as_mut() else {
            return Err(InferError::InvalidRequest(
                "this model has no decoder_step.onnx".into(),
            ));
        };
        cache.reserve_step()?;
        let slots = cache.step_rows();
        // Dead slots (GroupQueryAttention only) run as one-position rows whose logits are
        // dropped; spare slots past the rows the step runs are not touched.
        let mut ids = vec![0i64; slots];
        let mut pos = vec![0i64; slots];
        let mut seqlens = vec![0i32; slots];
        for r in 0..b {
            ids[r] = tokens[r] as i64;
            pos[r] = cache.next_positions()[r];
            seqlens[r] = cache.lens()[r] as i32;
        }
        let total = seqlens.iter().copied().max().unwrap_or(0) + 1;
        let input = |e: ort::Error| InferError::run("decode step input", e);
        let run = |e: ort::Error| InferError::run("decode step", e);
        let mut binding = step.create_binding().map_err(run)?;
        binding
            .bind_input(
                "input_ids",
                &Tensor::from_array(([slots, 1], ids)).map_err(input)?,
            )
            .map_err(input)?;
        binding
            .bind_input(
                "position_ids",
                &Tensor::from_array(([slots, 1], pos)).map_err(input)?,
            )
            .map_err(input)?;
        binding
            .bind_input(
                "seqlens_k",
                &Tensor::from_array(([slots], seqlens)).map_err(input)?,
            )
            .map_err(input)?;
        let shape: [usize; 0] = [];
        binding
            .bind_input(
                "total_sequence_length",
                &Tensor::from_array((shape, vec![total])).map_err(input)?,
            )
            .map_err(input)?;
        for (i, t) in cache.tensors_mut().iter_mut().enumerate() {
            binding
                .bind_input(self.past_names[i].as_str(), &*t)
                .map_err(input)?;
            binding
                .bind_output(self.present_names[i].as_str(), &mut *t)
                .map_err(input)?;
        }
        binding
            .bind_output_to_device("logits", &ort::memory::MemoryInfo::default())
            .map_err(input)?;
        let v = self.info.vocab_size;
        let logits = {
            let out = step.run_binding(&binding).map_err(run)?;
            let l = out["logits"]
                .try_extract_array::<f32>()
                .map_err(|e| InferError::run("decode step output", e))?;
            if l.shape() != [slots, 1, v] {
                return Err(InferError::OutputShape {
                    name: "logits".into(),
                    got: l.shape().to_vec(),
                    expected: format!("[{slots}, 1, {v}]"),
                });
            }
            l.slice(ndarray::s![..b, 0, ..]).to_owned()
        };
        drop(binding);
        cache.advance();
        Ok(logits)
    }

    /// An empty ragged cache shaped for this model.
    pub fn empty_ragged(&self) -> RaggedKv {
        RaggedKv::empty(
            2 * self.info.n_layers,
            self.info.n_heads,
            self.info.head_dim,
        )
        .spare_slots(self.step_spare_slots)
        .half(self.step_half)
    }

    /// Next-token logits for whole sequences without a cache (the reference the cached
    /// path is checked against, and `bench decode --no-kv-cache`).
    pub fn forward_full(
        &mut self,
        prefixes: &Array3<f32>,
        seqs: &[&[u32]],
    ) -> Result<Array2<f32>, InferError> {
        self.prefill(prefixes, seqs).map(|(logits, _)| logits)
    }

    /// Logits at every position of one whole sequence (T, V): row `t` is the model's
    /// distribution of token `t + 1` given tokens `0..=t` and the encoder's `prefix` (L, d).
    /// What a sequence that was not sampled (a library rig's tokens) is scored and refined by.
    pub fn teacher_forced(
        &mut self,
        prefix: ArrayView2<f32>,
        seq: &[u32],
    ) -> Result<Array2<f32>, InferError> {
        let info = &self.info;
        let (l, t) = (info.n_latents, seq.len());
        if prefix.dim() != (l, info.d_model) || t == 0 || t > info.max_tokens {
            return Err(InferError::InvalidRequest(format!(
                "teacher-forced run of {t} tokens with a prefix of shape {:?}",
                prefix.dim()
            )));
        }
        let ids =
            Array2::from_shape_vec((1, t), seq.iter().map(|&x| x as i64).collect()).expect("1×t");
        let pos = Array2::from_shape_fn((1, l + t), |(_, k)| k as i64);
        let mask = Array2::<i64>::ones((1, l + t));
        let empty_past = Array4::<f32>::zeros((1, info.n_heads, 0, info.head_dim));
        let prefix = prefix.insert_axis(Axis(0));
        let prefix_in =
            TensorRef::from_array_view(prefix).map_err(|e| InferError::run("decoder input", e))?;
        let (logits, ()) = self.run_decoder(
            ids,
            prefix_in.into(),
            pos,
            mask.view(),
            |_| Ok(TensorRef::from_array_view(empty_past.view())?.into()),
            0,
            |_| Ok(()),
        )?;
        Ok(logits.index_axis_move(Axis(0), 0))
    }

    /// Runs the decoder and hands the new keys and values (one (B, H, P + T, dh) view per
    /// cache tensor, checked) to `take` while the outputs are alive. Returns the logits of
    /// positions `from..T` (the last one when `from` is past it).
    // The arguments are the decoder graph's own inputs; a struct would only rename them.
    #[allow(clippy::too_many_arguments)]
    fn run_decoder<'v, R>(
        &mut self,
        ids: Array2<i64>,
        prefix: SessionInputValue<'v>,
        pos: Array2<i64>,
        mask: ArrayView2<'v, i64>,
        past: impl Fn(usize) -> ort::Result<SessionInputValue<'v>>,
        from: usize,
        take: impl FnOnce(&[ArrayView4<f32>]) -> Result<R, InferError>,
    ) -> Result<(Array3<f32>, R), InferError> {
        let (b, t) = ids.dim();
        let new_len = pos.dim().1;
        let input = |e: ort::Error| InferError::run("decoder input", e);
        let mut inputs: Vec<(Cow<str>, SessionInputValue)> =
            Vec::with_capacity(4 + self.past_names.len());
        inputs.push((
            "input_ids".into(),
            Tensor::from_array(ids).map_err(input)?.into(),
        ));
        inputs.push(("prefix".into(), prefix));
        inputs.push((
            "position_ids".into(),
            Tensor::from_array(pos).map_err(input)?.into(),
        ));
        inputs.push((
            "attention_mask".into(),
            TensorRef::from_array_view(mask).map_err(input)?.into(),
        ));
        for (i, name) in self.past_names.iter().enumerate() {
            inputs.push((Cow::Borrowed(name.as_str()), past(i).map_err(input)?));
        }
        let out = self
            .decoder
            .run(inputs)
            .map_err(|e| InferError::run("decoder", e))?;
        let v = self.info.vocab_size;
        let logits = out["logits"]
            .try_extract_array::<f32>()
            .map_err(|e| InferError::run("decoder output", e))?;
        if logits.shape() != [b, t, v] {
            return Err(InferError::OutputShape {
                name: "logits".into(),
                got: logits.shape().to_vec(),
                expected: format!("[{b}, {t}, {v}]"),
            });
        }
        let kept = logits
            .slice(ndarray::s![.., from.min(t - 1).., ..])
            .to_owned()
            .into_dimensionality::<Ix3>()
            .expect("rank 3");
        let want = [b, self.info.n_heads, new_len, self.info.head_dim];
        let mut new = Vec::with_capacity(self.new_names.len());
        for name in &self.new_names {
            let value = out
                .get(name.as_str())
                .ok_or_else(|| InferError::run("decoder output", format!("{name} missing")))?;
            let a = value
                .try_extract_array::<f32>()
                .map_err(|e| InferError::run("decoder output", e))?;
            if a.shape() != want {
                return Err(InferError::OutputShape {
                    name: name.clone(),
                    got: a.shape().to_vec(),
                    expected: format!("{want:?}"),
                });
            }
            new.push(a.into_dimensionality::<Ix4>().expect("shape checked"));
        }
        let r = take(&new)?;
        Ok((kept, r))
    }
}

/// The last position's logits (B, V) of a decoder output (B, T, V).
fn last_row(logits: Array3<f32>) -> Array2<f32> {
    let t = logits.dim().1;
    logits.index_axis_move(Axis(1), t - 1)
}
