// three.js plays an exported .glb in headless Chromium:
//   node export-three.mjs FILE.glb T1,T2,… [indices]
//   node export-three.mjs FILE.glb render T X1,Y1,X2,Y2,… W H
// GLTFLoader loads it, an AnimationMixer sets the first animation to each
// time, and for every puppet (a child of the scene) the chunk nodes shown
// (scale ≠ 0) are morphed on the CPU: base + Σ influence · target, from
// the mesh's morphTargetInfluences and geometry.morphAttributes (relative
// targets, as glTF's). Prints one JSON line {ok, samples: [{t, puppets:
// [{name, z, shown: [chunk names], positions: [x, y, z, …] of the first shown,
// indices: its triangles' vertex indices in draw order (with `indices`)}]}],
// skinned: {MESH: [x, y, z, …]}}], duration} — z is the puppet node's, the
// depth three.js sorts it by; skinned, each skinned mesh's vertices as
// three.js skins them.

import fs from 'node:fs';
import path from 'node:path';
import { HERE, launch, run, serve } from './export-common.mjs';

const PAGE = `<!doctype html><meta charset="utf-8"><title>export check</title><link rel="icon" href="data:,">
<script type="importmap">{"imports": {"three": "/three/build/three.module.js", "three/addons/": "/three/examples/jsm/"}}</script>
<script type="module">
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
window.sample = async (url, times, withIndices) => {
  const gltf = await new GLTFLoader().loadAsync(url);
  const clip = gltf.animations[0];
  const samples = [];
  for (const t of times) {
    // A fresh mixer per time: setTime on a finished LoopOnce action would not move it.
    const mixer = new THREE.AnimationMixer(gltf.scene);
    const action = mixer.clipAction(clip);
    action.setLoop(THREE.LoopOnce);
    action.clampWhenFinished = true;
    action.play();
    mixer.setTime(t);
    const puppets = gltf.scene.children.map((puppet) => {
      const chunks = [];
      puppet.traverse((o) => { if (o.isMesh) chunks.push(o); });
      const shown = chunks.filter((m) => m.scale.x !== 0 && m.scale.y !== 0 && m.scale.z !== 0);
      let positions = null;
      if (shown.length) {
        const m = shown[0];
        const base = m.geometry.attributes.position;
        const targets = m.geometry.morphAttributes.position ?? [];
        const w = m.morphTargetInfluences ?? [];
        positions = [];
        for (let i = 0; i < base.count; i++) {
          let x = base.getX(i), y = base.getY(i), z = base.getZ(i);
          targets.forEach((tgt, j) => {
            if (!w[j]) return;
            x += w[j] * tgt.getX(i); y += w[j] * tgt.getY(i); z += w[j] * tgt.getZ(i);
          });
          positions.push(x, y, z);
        }
        if (!m.geometry.morphTargetsRelative && targets.length) throw new Error('targets are not relative');
      }
      const indices = withIndices && shown.length ? Array.from(shown[0].geometry.index.array) : undefined;
      return {
        name: puppet.name, z: puppet.position.z, chunks: chunks.length,
        shown: shown.map((m) => m.name), positions, indices,
      };
    });
    // Skinned meshes (skeleton puppets): three.js's own skinning of each
    // vertex, bones posed by the mixer.
    gltf.scene.updateMatrixWorld(true);
    const skinned = {};
    gltf.scene.traverse((o) => {
      if (!o.isSkinnedMesh) return;
      o.skeleton.update();
      const v = new THREE.Vector3();
      const out = [];
      for (let i = 0; i < o.geometry.attributes.position.count; i++) {
        o.getVertexPosition(i, v);
        v.applyMatrix4(o.matrixWorld);
        out.push(v.x, v.y, v.z);
      }
      skinned[o.name] = out;
    });
    samples.push({ t, puppets, skinned });
    mixer.stopAllAction();
  }
  return { duration: clip.duration, samples };
};
// Renders the stage at time t as a viewer would (WebGL, an orthographic
// camera in front of the stage, y up) and returns the colour at each stage
// point: what three.js draws on top where puppets overlap.
window.render = async (url, t, points, stage) => {
  const gltf = await new GLTFLoader().loadAsync(url);
  const mixer = new THREE.AnimationMixer(gltf.scene);
  const action = mixer.clipAction(gltf.animations[0]);
  action.play();
  mixer.setTime(t);
  const [w, h] = [stage.width, stage.height];
  const renderer = new THREE.WebGLRenderer({ preserveDrawingBuffer: true });
  renderer.setSize(w, h);
  document.body.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0, 0, 0);
  scene.add(gltf.scene);
  const camera = new THREE.OrthographicCamera(0, w, h, 0, 0.1, 10 * Math.max(w, h));
  camera.position.set(0, 0, 5 * Math.max(w, h));
  renderer.render(scene, camera);
  const gl = renderer.getContext();
  return points.map(([x, y]) => {
    const px = new Uint8Array(4);
    gl.readPixels(Math.round(x), Math.round(y), 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
    return Array.from(px.slice(0, 3));
  });
};
window.ready = true;
</script>`;

run(async () => {
  const [file, list, extra, ...rest] = process.argv.slice(2);
  const { server, url } = await serve({
    '/': { body: PAGE, type: 'text/html' },
    '/model.glb': { body: fs.readFileSync(file), type: 'model/gltf-binary' },
    '/three/': path.join(HERE, 'node_modules/three'),
  });
  const rendering = list === 'render';
  const browser = await launch(rendering ? { webgl: true } : {});
  try {
    await browser.page.goto(`${url}/`);
    await browser.page.waitForFunction(() => window.ready === true);
    let result;
    if (rendering) {
      // render T X1,Y1,… W H: the colours at those stage points.
      const numbers = rest[0].split(',').map(Number);
      const points = [];
      for (let i = 0; i + 1 < numbers.length; i += 2) points.push([numbers[i], numbers[i + 1]]);
      const stage = { width: Number(rest[1]), height: Number(rest[2]) };
      result = { colours: await browser.page.evaluate(
        ([u, t, p, s]) => window.render(u, t, p, s), [`${url}/model.glb`, Number(extra), points, stage],
      ) };
    } else {
      const times = list.split(',').map(Number);
      result = await browser.page.evaluate(
        ([u, ts, ix]) => window.sample(u, ts, ix), [`${url}/model.glb`, times, extra === 'indices'],
      );
    }
    if (browser.errors.length) throw new Error(browser.errors.join('\n'));
    return result;
  } finally {
    await browser.close();
    server.close();
  }
});
