// Validate a .glb with the Khronos glTF validator; prints the report's issue summary as JSON.
// usage: node tools/validate_gltf.js FILE.glb
const fs = require("fs");
const path = require("path");
const validator = require(path.join(__dirname, "node_modules", "gltf-validator"));

const file = process.argv[2];
validator
  .validateBytes(new Uint8Array(fs.readFileSync(file)), { maxIssues: 100 })
  .then((report) => {
    console.log(JSON.stringify({
      numErrors: report.issues.numErrors,
      numWarnings: report.issues.numWarnings,
      messages: report.issues.messages.map((m) => `${m.severity} ${m.code} ${m.pointer || ""} ${m.message}`),
    }));
  })
  .catch((err) => {
    console.error(String(err));
    process.exit(1);
  });
