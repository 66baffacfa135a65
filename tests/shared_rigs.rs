//! Every artist rig in ../shared/rigs loads and yields its ground truth.
mod common;

use rigserve::mesh::{load, Limits};
use rigserve::rig::groundtruth::extract;

#[test]
fn every_shared_rig_loads_with_ground_truth() {
    let Some(dir) = common::shared_rigs() else {
        return;
    };
    let entries = common::manifest(&dir);
    assert!(entries.len() >= 100);
    let text = std::fs::read_to_string(dir.join("manifest.tsv")).unwrap();
    let header: Vec<&str> = text.lines().next().unwrap().split('\t').collect();
    let jcol = header.iter().position(|h| *h == "joints").unwrap();
    let expected_joints: Vec<usize> = text
        .lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.split('\t').nth(jcol).unwrap().parse().unwrap())
        .collect();
    let (mut near, mut total) = (0, 0);
    for (e, joints) in entries.iter().zip(expected_joints) {
        let bytes = std::fs::read(dir.join(&e.file)).unwrap();
        let asset =
            load(&bytes, &Limits::default()).unwrap_or_else(|err| panic!("{}: {err}", e.file));
        let gt = extract(&asset)
            .unwrap_or_else(|err| panic!("{}: {err}", e.file))
            .unwrap_or_else(|| panic!("{}: no skin", e.file));
        gt.skeleton
            .validate(10_000)
            .unwrap_or_else(|err| panic!("{}: {err}", e.file));
        assert_eq!(gt.skeleton.len(), joints, "{}", e.file);
        let weighted = gt
            .weights
            .per_vertex
            .iter()
            .filter(|w| !w.is_empty())
            .count();
        assert!(weighted > 0, "{}", e.file);
        // Joints lie near the mesh (IK targets and pole bones may sit outside it).
        let (lo, hi) = asset.mesh.bounds();
        let pad = (hi - lo) * 0.25;
        let inside = gt
            .skeleton
            .bones
            .iter()
            .filter(|b| b.head.cmpge(lo - pad).all() && b.head.cmple(hi + pad).all())
            .count();
        // A frame mix-up (bind space vs. scene) moves every joint off the mesh; odd
        // artist rigs (a chest hinge outside the lid) move only a few.
        assert!(
            inside * 2 >= gt.skeleton.len(),
            "{}: only {inside} of {} joints near the mesh",
            e.file,
            gt.skeleton.len()
        );
        near += inside;
        total += gt.skeleton.len();
    }
    assert!(
        near * 100 >= total * 97,
        "only {near} of {total} joints lie near their meshes"
    );
}
