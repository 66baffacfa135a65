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

#[test]
fn every_shared_rig_tokenization_round_trips() {
    use rigserve::mesh::Normalization;
    use rigserve::rig::template::match_mixamo;
    use rigserve::rig::tokenizer::{detokenize, same_topology, tokenize, tokenize_with_order, ALT};
    // Half a bin per axis, plus float slack.
    const HALF_BIN: f32 = 1.0 / 256.0 + 1e-5;
    let Some(dir) = common::shared_rigs() else {
        return;
    };
    let (mut templated, mut exact, mut with_alt, mut total) = (0, 0, 0, 0);
    let mut failures = Vec::new();
    for e in common::manifest(&dir) {
        total += 1;
        let bytes = std::fs::read(dir.join(&e.file)).unwrap();
        let asset = load(&bytes, &Limits::default()).unwrap();
        let gt = extract(&asset).unwrap().unwrap();
        let norm = Normalization::from_points(&asset.mesh.positions);
        let mut skel = match_mixamo(&gt.skeleton).unwrap_or(gt.skeleton);
        templated += skel.template.is_some() as usize;
        // Joints outside the mesh's box (IK targets, end bones past the tip) cannot be
        // written: coordinates are clipped to [-1, 1], so compare against that.
        skel.map_points(|p| {
            norm.apply(p)
                .clamp(glam::Vec3::splat(-1.0), glam::Vec3::splat(1.0))
        });
        skel.category = Some(e.category.clone());
        let (tokens, order) =
            tokenize_with_order(&skel).unwrap_or_else(|err| panic!("{}: {err}", e.file));
        with_alt += tokens.contains(&ALT) as usize;
        let back = detokenize(&tokens).unwrap_or_else(|err| panic!("{}: {err}", e.file));
        assert_eq!(back.len(), skel.len(), "{}", e.file);
        assert_eq!(order.len(), skel.len(), "{}", e.file);
        assert_eq!(
            back.category.as_deref(),
            Some(e.category.as_str()),
            "{}",
            e.file
        );
        // Bone for bone through the emission order, so coincident joints cannot hide a
        // rewired tree behind a lucky (or unlucky) pairing by position.
        let mut at = vec![usize::MAX; skel.len()];
        for (k, &i) in order.iter().enumerate() {
            assert_eq!(at[i], usize::MAX, "{}: bone {i} written twice", e.file);
            at[i] = k;
        }
        let wrong = order.iter().enumerate().find_map(|(k, &i)| {
            let (o, d) = (&skel.bones[i], &back.bones[k]);
            let parent = o.parent.map(|p| at[p]);
            let gap = (d.head - o.head).abs();
            if d.parent != parent {
                Some(format!(
                    "decoded bone {k} is {} (bone {i}); its parent should be {parent:?}, is {:?}",
                    o.name, d.parent
                ))
            } else if d.spring != o.spring {
                Some(format!(
                    "decoded bone {k} ({}) lost its spring flag",
                    o.name
                ))
            } else if !gap.cmple(glam::Vec3::splat(HALF_BIN)).all() {
                Some(format!(
                    "decoded bone {k} ({}) is {gap:?} off {:?}",
                    o.name, o.head
                ))
            } else {
                None
            }
        });
        match wrong {
            Some(why) => failures.push(format!("{}: {why}", e.file)),
            None => exact += 1,
        }
        // The order-free check (what predictions are compared with) must agree.
        if let Err(why) = same_topology(&skel, &back, HALF_BIN) {
            failures.push(format!("{}: same_topology: {why}", e.file));
        }
        if tokenize(&back).as_ref() != Ok(&tokens) {
            failures.push(format!("{}: re-tokenizing changed the tokens", e.file));
        }
    }
    eprintln!(
        "{exact} of {total} rigs round-trip exactly; {with_alt} needed <alt>; \
         {templated} mapped onto the Mixamo template"
    );
    assert!(templated > 0, "no humanoid matched the Mixamo template");
    assert!(
        failures.is_empty(),
        "round trip changed {} rigs:\n{}",
        failures.len(),
        failures.join("\n")
    );
}
