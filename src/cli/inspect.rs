use anyhow::Context;
use rigserve::mesh::{self, Limits};
use rigserve::rig::groundtruth;
use std::path::Path;

pub fn run(file: &Path, json: bool, limits: &Limits) -> anyhow::Result<()> {
    let bytes = std::fs::read(file).with_context(|| format!("reading {}", file.display()))?;
    let asset = mesh::load(&bytes, limits).map_err(|e| anyhow::anyhow!("{} [{}]", e, e.code()))?;
    let gt = groundtruth::extract(&asset).map_err(|e| anyhow::anyhow!("{} [{}]", e, e.code()))?;
    let Some(gt) = gt else {
        anyhow::bail!(
            "{} has no skinned mesh, so no bone tree [no_skin]",
            file.display()
        );
    };
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&rigserve::export::bone_tree(&gt.skeleton))?
        );
        return Ok(());
    }
    let m = &asset.mesh;
    println!(
        "{}: {:?}, {} vertices, {} triangles, {} primitives, {} bones, {} unweighted skinned vertices",
        file.display(),
        asset.format,
        m.positions.len(),
        m.triangles.len(),
        m.parts.len(),
        gt.skeleton.len(),
        gt.unweighted
    );
    let children = gt.skeleton.children();
    let mut stack: Vec<(usize, usize)> = gt.skeleton.roots().map(|r| (r, 0)).collect();
    stack.reverse();
    while let Some((b, depth)) = stack.pop() {
        let bone = &gt.skeleton.bones[b];
        println!(
            "{:indent$}{} {:.4?}",
            "",
            bone.name,
            bone.head.to_array(),
            indent = depth * 2
        );
        stack.extend(children[b].iter().rev().map(|&c| (c, depth + 1)));
    }
    Ok(())
}
