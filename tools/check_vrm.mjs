// Load a .vrm with three.js's GLTFLoader and pixiv's three-vrm (a real VRM 1.0 and 0.x consumer), in Node,
// and print what it made of the file as JSON: meta, humanoid bones, each expression's effect on
// the morph targets, the gaze, the first-person annotations and where the head ends up.
// usage: node tools/check_vrm.mjs FILE.vrm
//
// Node has no DOM to decode images in: a GLTFLoader plugin hands back an empty THREE.Texture for
// every glTF texture (the texture's presence is still reported), so everything but the pixels is
// three.js's own loading.
import fs from "fs";
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { VRMLoaderPlugin, VRMUtils } from "@pixiv/three-vrm";

class UndecodedTextures {
  constructor(parser) {
    this.name = "faceanim_undecoded_textures";
    this.parser = parser;
  }

  loadTexture(index) {
    const texture = new THREE.Texture();
    texture.userData.gltfTexture = index;
    return Promise.resolve(texture);
  }
}

const warnings = [];
for (const level of ["warn", "error"]) {
  const original = console[level];
  console[level] = (...args) => {
    warnings.push(`${level}: ${args.map(String).join(" ")}`);
    if (level === "error") original(...args);
  };
}

const file = process.argv[2];
const bytes = fs.readFileSync(file);
const data = bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength);
const loader = new GLTFLoader();
loader.register((parser) => new UndecodedTextures(parser));
loader.register((parser) => new VRMLoaderPlugin(parser));

const round = (v) => v.toArray().map((x) => Math.round(x * 1e6) / 1e6);

loader.parse(data, "", (gltf) => {
  const vrm = gltf.userData.vrm;
  if (!vrm) {
    console.log(JSON.stringify({ vrm: false, warnings }));
    return;
  }
  VRMUtils.rotateVRM0(vrm); // a VRM 0.x avatar faces -Z: turned to face +Z as three-vrm's users do
  vrm.scene.updateMatrixWorld(true);
  const meshes = [];
  vrm.scene.traverse((o) => { if (o.isMesh) meshes.push(o); });
  const em = vrm.expressionManager;
  const names = em ? Object.keys(em.expressionMap) : [];
  const influences = () => meshes.map((m) => Array.from(m.morphTargetInfluences || []));
  // each expression alone at 1: which morph targets it moves, and by how much
  const effects = {};
  for (const name of names) {
    for (const other of names) em.setValue(other, 0);
    em.setValue(name, 1);
    em.update();
    effects[name] = influences().map((w) => Object.fromEntries(w.map((x, i) => [i, x]).filter(([, x]) => x !== 0)));
  }
  for (const other of names) em.setValue(other, 0);
  em.update();

  // gaze: a point 1 m ahead of the head and 1 m to the avatar's left (+X), then as high above it
  const gaze = {};
  const world = new THREE.Object3D();
  const head = vrm.humanoid.getRawBoneNode("head");
  const headWorld = head.getWorldPosition(new THREE.Vector3());
  if (vrm.lookAt) {
    for (const [label, offset] of [["left", [1, 0, 1]], ["up", [0, 1, 1]]]) {
      const target = new THREE.Object3D();
      target.position.copy(headWorld).add(new THREE.Vector3(...offset));
      world.add(target); // world coordinates (vrm.scene may be turned: rotateVRM0)
      target.updateMatrixWorld(true);
      vrm.lookAt.target = target;
      vrm.update(1 / 30);
      gaze[label] = Object.fromEntries(["lookLeft", "lookRight", "lookUp", "lookDown"]
        .filter((n) => em.getExpression(n)).map((n) => [n, em.getValue(n)]));
      world.remove(target);
    }
    vrm.lookAt.target = null;
  }

  const bones = {};
  for (const [bone, node] of Object.entries(vrm.humanoid.humanBones)) {
    if (node && node.node) bones[bone] = node.node.name;
  }
  const box = new THREE.Box3();
  for (const m of meshes) box.expandByObject(m);
  const meta = { ...vrm.meta };
  const firstPerson = vrm.firstPerson
    ? vrm.firstPerson.meshAnnotations.map((a) => ({ type: a.type, meshes: a.meshes.length })) : null;
  console.log(JSON.stringify({
    vrm: true,
    meta,
    humanBones: bones,
    meshes: meshes.map((m) => ({ name: m.name, targets: (m.morphTargetInfluences || []).length,
      morphTargetDictionary: m.morphTargetDictionary || {}, textured: Boolean(m.material && m.material.map),
      parentIsHead: m.parent === head || m.parent.parent === head })),
    expressions: names,
    effects,
    lookAt: vrm.lookAt ? { type: vrm.lookAt.applier.constructor.type, offsetFromHeadBone: round(vrm.lookAt.offsetFromHeadBone) } : null,
    gaze,
    firstPerson,
    headWorld: round(headWorld),
    meshBox: { min: round(box.min), max: round(box.max) },
    warnings,
  }));
}, (err) => {
  console.error(String(err && err.stack ? err.stack : err));
  process.exit(1);
});
