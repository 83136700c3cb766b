// Validates one glTF or GLB file with the Khronos glTF validator (npm gltf-validator, pinned in package-lock.json)
// and prints its report as one line of JSON; tests/material_export_test.cpp reads it.
//     node validate.js FILE
// Exit status 0 when the validator ran (whatever it found), 1 when it could not, 2 on bad usage. External
// resources are not loaded: Loomlight's files embed their buffer, and one that did not would be reported.
'use strict';
const fs = require('fs');
const path = require('path');
const validator = require('gltf-validator');

if (process.argv.length !== 3) {
  console.error('usage: node validate.js FILE');
  process.exit(2);
}
const file = process.argv[2];
validator
  .validateBytes(new Uint8Array(fs.readFileSync(file)), {
    uri: path.basename(file),
    maxIssues: 0,  // every issue
    writeTimestamp: false,
  })
  .then((report) => process.stdout.write(JSON.stringify(report) + '\n'))
  .catch((error) => {
    console.error('gltf-validator could not validate ' + file + ': ' + error);
    process.exit(1);
  });
