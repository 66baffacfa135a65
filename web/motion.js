// The test motion for a rig whose GLB carries none (submitted without animation=preview):
// the generic sway of src/export/animation.rs, rebuilt here as a three.js clip so the
// page can always show the deformation. Joints of rigserve's GLBs have no rest rotation,
// so a joint's quaternion is its turn about its head, as on the Rust side.
import * as THREE from 'three';

export const SECONDS = 2;
const FPS = 20;

function swayAxis(bone) {
  const d = new THREE.Vector3().fromArray(bone.tail).sub(new THREE.Vector3().fromArray(bone.head));
  const axis = d.normalize().cross(new THREE.Vector3(0, 1, 0));
  if (axis.lengthSq() > 1e-6) return axis.normalize();
  return new THREE.Vector3(1, 0, 0);
}

// `tree` is skeleton.json; `bones` the three.js bones in the same (skin joint) order.
export function swayClip(tree, bones) {
  const frames = SECONDS * FPS;
  const times = Array.from({ length: frames + 1 }, (_, k) => k / FPS);
  const depth = [];
  const tracks = tree.bones.map((b, i) => {
    depth[i] = b.parent == null ? 0 : depth[b.parent] + 1;
    const axis = b.parent == null ? new THREE.Vector3(0, 1, 0) : swayAxis(b);
    const amp = THREE.MathUtils.degToRad(b.parent == null ? 8 : 12);
    const values = [];
    for (const t of times) {
      const phase = (2 * Math.PI * t) / SECONDS - 0.7 * depth[i];
      const q = new THREE.Quaternion().setFromAxisAngle(axis, amp * Math.sin(phase));
      values.push(q.x, q.y, q.z, q.w);
    }
    return new THREE.QuaternionKeyframeTrack(`${bones[i].uuid}.quaternion`, times, values);
  });
  return new THREE.AnimationClip('sway', SECONDS, tracks);
}
