#!/usr/bin/env node
// Validate glTF/GLB files with the Khronos glTF validator (npm gltf-validator), one node process for all.
// Usage: node .ci/validate_gltf.js FILE...   -> one JSON object on stdout:
//   {"validator": "<version>", "reports": {"<file>": {"errors": n, "warnings": n, "infos": n, "hints": n,
//                                                     "messages": [{"code", "severity", "pointer", "message"}]}}}
// Exit status 0 when every file has zero errors and zero warnings, 1 otherwise, 3 when the validator is absent.
"use strict";
const fs = require("fs");
const path = require("path");

let validator;
for (const base of [path.join(__dirname, "node_modules"), process.env.GLTF_VALIDATOR_PATH || ""]) {
  if (!base) continue;
  try { validator = require(path.join(base, "gltf-validator")); break; } catch (e) { /* next */ }
}
if (!validator) {
  try { validator = require("gltf-validator"); } catch (e) {
    process.stderr.write("gltf-validator is not installed: run .ci/run or `npm install --prefix .ci`\n");
    process.exit(3);
  }
}

async function validate(file) {
  const bytes = new Uint8Array(fs.readFileSync(file));
  const report = await validator.validateBytes(bytes, {
    uri: path.basename(file),
    maxIssues: 200,
    externalResourceFunction: (uri) => new Promise((resolve, reject) => {
      fs.readFile(path.resolve(path.dirname(file), decodeURIComponent(uri)), (err, data) =>
        err ? reject(err.toString()) : resolve(new Uint8Array(data)));
    }),
  });
  const issues = report.issues;
  return {
    errors: issues.numErrors, warnings: issues.numWarnings, infos: issues.numInfos, hints: issues.numHints,
    messages: issues.messages.map((m) => ({ code: m.code, severity: m.severity, pointer: m.pointer || "",
                                            message: m.message })),
  };
}

(async () => {
  const files = process.argv.slice(2);
  const reports = {};
  let ok = true;
  for (const file of files) {
    try {
      reports[file] = await validate(file);
    } catch (e) {
      reports[file] = { errors: 1, warnings: 0, infos: 0, hints: 0,
                        messages: [{ code: "UNREADABLE", severity: 0, pointer: "", message: String(e) }] };
    }
    if (reports[file].errors || reports[file].warnings) ok = false;
  }
  // exit once stdout is flushed: process.exit() right after write() cut a pipe's output at its 64 KiB buffer
  process.exitCode = ok ? 0 : 1;
  process.stdout.write(JSON.stringify({ validator: validator.version(), reports }) + "\n");
})();
