// Spine's own runtime (spine-core 4.2) on an exported skeleton:
//   node export-spine.mjs FILE.json ANIMATION T1,T2,…
// reads the JSON with SkeletonJson — through the atlas beside it (FILE with
// .atlas) and spine-core's AtlasAttachmentLoader when there is one, as a
// player loads it (a region missing from the atlas fails), else an
// attachment loader that makes mesh attachments without one — applies the
// animation at each time and
// prints one JSON line {ok, samples: [{t, slots: {SLOT: [x0, y0, x1, y1, …]},
// attached: {SLOT: {name, triangles}}}]} of world vertices, in the
// attachment's vertex order, and the mesh attachment each slot shows, the animation's duration
// and the atlas's pages ({name, width, height}).

import fs from 'node:fs';
import {
  AtlasAttachmentLoader, BoundingBoxAttachment, ClippingAttachment, MeshAttachment, MixBlend, MixDirection, PathAttachment,
  Physics, PointAttachment, RegionAttachment, Skeleton, SkeletonJson, TextureAtlas,
} from '@esotericsoftware/spine-core';
import { run } from './export-common.mjs';

const noAtlas = {
  newRegionAttachment: (skin, name, path) => new RegionAttachment(name, path),
  newMeshAttachment: (skin, name, path) => new MeshAttachment(name, path),
  newBoundingBoxAttachment: (skin, name) => new BoundingBoxAttachment(name),
  newPathAttachment: (skin, name) => new PathAttachment(name),
  newPointAttachment: (skin, name) => new PointAttachment(name),
  newClippingAttachment: (skin, name) => new ClippingAttachment(name),
};

run(async () => {
  const [file, name, list] = process.argv.slice(2);
  const atlasFile = file.replace(/\.json$/, '.atlas');
  const atlas = fs.existsSync(atlasFile) ? new TextureAtlas(fs.readFileSync(atlasFile, 'utf8')) : null;
  const loader = atlas ? new AtlasAttachmentLoader(atlas) : noAtlas;
  const data = new SkeletonJson(loader).readSkeletonData(fs.readFileSync(file, 'utf8'));
  const animation = data.findAnimation(name);
  if (!animation) throw new Error(`no animation ${name}`);
  const skeleton = new Skeleton(data);
  const samples = [];
  for (const t of list.split(',').map(Number)) {
    skeleton.setToSetupPose();
    animation.apply(skeleton, t, t, false, null, 1, MixBlend.setup, MixDirection.mixIn);
    skeleton.updateWorldTransform(Physics.none);
    const slots = {};
    for (const slot of skeleton.drawOrder) {
      const a = slot.getAttachment();
      if (!(a instanceof MeshAttachment)) continue;
      const world = new Array(a.worldVerticesLength);
      a.computeWorldVertices(slot, 0, a.worldVerticesLength, world, 0, 2);
      slots[slot.data.name] = world;
    }
    const attached = {};
    for (const slot of skeleton.slots) {
      const a = slot.getAttachment();
      if (a instanceof MeshAttachment) attached[slot.data.name] = { name: a.name, triangles: Array.from(a.triangles) };
    }
    samples.push({ t, slots, attached });
  }
  return {
    version: data.version, duration: animation.duration, hull: Object.fromEntries(
      skeleton.slots.map((s) => [s.data.name, s.getAttachment()?.hullLength / 2])),
    samples,
    atlas: atlas && atlas.pages.map((p) => ({ name: p.name, width: p.width, height: p.height })),
  };
});
