// Validate a glTF/GLB file with the Khronos glTF validator (npm package `gltf-validator`)
// and print the report as JSON on stdout.
//
//   node tests/io/gltf_validator.mjs FILE.glb
//
// Exit status: 0 when the report was printed (whatever it says), 2 when the validator could
// not run (bad arguments, unreadable file, package missing).
import { readFile } from "node:fs/promises";
import { basename } from "node:path";

const file = process.argv[2];
if (!file) {
  console.error("usage: node gltf_validator.mjs FILE.glb");
  process.exit(2);
}

let validator;
try {
  validator = (await import("gltf-validator")).default;
} catch (err) {
  console.error(`gltf-validator is not installed: ${err.message}`);
  process.exit(2);
}

try {
  const data = new Uint8Array(await readFile(file));
  const report = await validator.validateBytes(data, {
    uri: basename(file),
    maxIssues: 0,
    writeTimestamp: false,
  });
  process.stdout.write(JSON.stringify(report, null, 1) + "\n");
} catch (err) {
  console.error(`validation failed: ${err}`);
  process.exit(2);
}
