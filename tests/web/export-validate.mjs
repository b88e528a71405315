// The Khronos glTF validator on a .glb: node export-validate.mjs FILE.glb
// Prints one JSON line {ok, issues: {numErrors, numWarnings, numInfos,
// numHints, messages}}; ok says the validator ran, not that it passed.

import fs from 'node:fs';
import validator from 'gltf-validator';
import { run } from './export-common.mjs';

run(async () => {
  const file = process.argv[2];
  const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
    uri: file,
    maxIssues: 1000,
    writeTimestamp: false,
  });
  return { issues: report.issues, info: report.info };
});
