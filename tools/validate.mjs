#!/usr/bin/env node
// Runs the Khronos glTF validator on each file given and prints one JSON line per file:
//   {"file", "numErrors", "numWarnings", "numInfos", "errors": [first few], "warnings": [...]}
// Exits 1 when any file has an error (or cannot be read), so scripts and tests can gate on it.
//
// Usage: node tools/validate.mjs [--max-issues N] [--allow-missing-external] [--bone-tree-schema SCHEMA] FILE...
//   --allow-missing-external
//                       do not count resources referenced by URI that cannot be loaded
//                       (rigserve keeps relative image names of an upload whose images
//                       were not sent); those that exist are still validated
//   --bone-tree-schema  also check the bone tree at scenes[scene].extras.rigserve against
//                       the JSON Schema (proto/bone_tree.schema.json); a missing or
//                       invalid tree counts as an error ("boneTree" lists why)
import fs from "node:fs/promises";
import path from "node:path";
import { createRequire } from "node:module";

// The packages ship CommonJS; createRequire finds them in tools/node_modules wherever the
// caller's working directory is.
const require = createRequire(import.meta.url);
const validator = require("gltf-validator");

const SHOWN = 5;

function glbJson(bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (bytes.length < 20 || view.getUint32(0, true) !== 0x46546c67) {
    throw new Error("not a GLB");
  }
  const length = view.getUint32(12, true);
  return JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + length)));
}

function boneTreeProblems(bytes, validateTree) {
  const json = glbJson(bytes);
  const tree = json.scenes?.[json.scene ?? 0]?.extras?.rigserve;
  if (tree === undefined) {
    return ["no bone tree at scenes[scene].extras.rigserve"];
  }
  if (validateTree(tree)) {
    return [];
  }
  return validateTree.errors.slice(0, SHOWN).map((e) => `${e.instancePath} ${e.message}`);
}

async function validateOne(file, opts) {
  const bytes = new Uint8Array(await fs.readFile(file));
  const report = await validator.validateBytes(bytes, {
    uri: path.basename(file),
    maxIssues: opts.maxIssues,
    // The validator reports IO_ERROR only for resources it fails to load.
    ignoredIssues: opts.allowMissingExternal ? ["IO_ERROR"] : [],
    externalResourceFunction: async (uri) =>
      new Uint8Array(await fs.readFile(path.resolve(path.dirname(file), decodeURIComponent(uri)))),
  });
  const issues = report.issues;
  const pick = (severity) =>
    issues.messages
      .filter((m) => m.severity === severity)
      .slice(0, SHOWN)
      .map((m) => `${m.code} ${m.pointer ?? ""}: ${m.message}`);
  const line = {
    file,
    numErrors: issues.numErrors,
    numWarnings: issues.numWarnings,
    numInfos: issues.numInfos,
    errors: pick(0),
    warnings: pick(1),
  };
  if (opts.validateTree) {
    line.boneTree = boneTreeProblems(bytes, opts.validateTree);
    line.numErrors += line.boneTree.length;
  }
  return line;
}

async function main() {
  const args = process.argv.slice(2);
  const opts = { maxIssues: 0, allowMissingExternal: false, validateTree: null }; // 0 = no cap
  const files = [];
  for (let i = 0; i < args.length; i++) {
    if (args[i] === "--max-issues") {
      opts.maxIssues = Number(args[++i]);
    } else if (args[i] === "--allow-missing-external") {
      opts.allowMissingExternal = true;
    } else if (args[i] === "--bone-tree-schema") {
      const Ajv2020 = require("ajv/dist/2020").default;
      const schema = JSON.parse(await fs.readFile(args[++i], "utf8"));
      opts.validateTree = new Ajv2020({ allErrors: true, strict: true }).compile(schema);
    } else {
      files.push(args[i]);
    }
  }
  if (files.length === 0) {
    console.error(
      "usage: node tools/validate.mjs [--max-issues N] [--allow-missing-external] [--bone-tree-schema SCHEMA] FILE...",
    );
    process.exit(2);
  }
  let failed = false;
  for (const file of files) {
    let line;
    try {
      line = await validateOne(file, opts);
    } catch (e) {
      line = { file, numErrors: 1, numWarnings: 0, numInfos: 0, errors: [String(e)], warnings: [] };
    }
    failed ||= line.numErrors > 0;
    console.log(JSON.stringify(line));
  }
  process.exit(failed ? 1 : 0);
}

main();
