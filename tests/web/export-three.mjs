// three.js plays an exported .glb in headless Chromium:
//   node export-three.mjs FILE.glb T1,T2,… [indices]
// GLTFLoader loads it, an AnimationMixer sets the first animation to each
// time, and for every puppet (a child of the scene) the chunk nodes shown
// (scale ≠ 0) are morphed on the CPU: base + Σ influence · target, from
// the mesh's morphTargetInfluences and geometry.morphAttributes (relative
// targets, as glTF's). Prints one JSON line {ok, samples: [{t, puppets:
// [{name, z, shown: [chunk names], positions: [x, y, z, …] of the first shown,
// indices: its triangles' vertex indices in draw order (with `indices`)}]}],
// duration} — z is the puppet node's, the depth three.js sorts it by.

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
    samples.push({ t, puppets });
    mixer.stopAllAction();
  }
  return { duration: clip.duration, samples };
};
window.ready = true;
</script>`;

run(async () => {
  const [file, list, extra] = process.argv.slice(2);
  const times = list.split(',').map(Number);
  const { server, url } = await serve({
    '/': { body: PAGE, type: 'text/html' },
    '/model.glb': { body: fs.readFileSync(file), type: 'model/gltf-binary' },
    '/three/': path.join(HERE, 'node_modules/three'),
  });
  const browser = await launch();
  try {
    await browser.page.goto(`${url}/`);
    await browser.page.waitForFunction(() => window.ready === true);
    const result = await browser.page.evaluate(
      ([u, ts, ix]) => window.sample(u, ts, ix), [`${url}/model.glb`, times, extra === 'indices'],
    );
    if (browser.errors.length) throw new Error(browser.errors.join('\n'));
    return result;
  } finally {
    await browser.close();
    server.close();
  }
});
