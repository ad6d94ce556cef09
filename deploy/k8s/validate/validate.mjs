// Validates Kubernetes manifests offline against the API schemas that the
// kubernetes-models package carries (generated from Kubernetes' OpenAPI
// definitions), and strictly: kubernetes-models' validators allow fields the
// schema does not know (as the API server's lenient decoding does), so a
// misspelled field would pass; this script also walks each object against
// the package's type declarations and rejects every unknown field.
//
//   node validate.mjs MANIFEST.yaml...
//
// The packages come from node_modules in $PENUMBRA_K8S_NODE_MODULES (the
// build directory, where tests/deploy/k8s_manifests_test.sh runs `npm ci`),
// else beside this file. Exit 0 when every document of every file is valid;
// 1 with one line per problem otherwise.

import { existsSync, readFileSync } from "node:fs";
import { createRequire } from "node:module";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const modules = process.env.PENUMBRA_K8S_NODE_MODULES || path.join(here, "node_modules");
const require = createRequire(path.join(modules, "noop.js"));
const YAML = require("yaml");
const modelsRoot = path.join(modules, "kubernetes-models");

// Kinds that are not Kubernetes API objects but live beside them.
const KUSTOMIZATION = "kustomize.config.k8s.io/v1beta1/Kustomization";

// --- Strict field check, from the packages' .d.ts declarations -------------

const declarations = new Map(); // .d.ts path -> {props: Map(name -> type), imports: Map(name -> path)}

function resolveImport(fromFile, spec) {
  const base = spec.startsWith(".") ? path.resolve(path.dirname(fromFile), spec) : path.join(modules, spec);
  for (const candidate of [base + ".d.ts", path.join(base, "index.d.ts")]) if (existsSync(candidate)) return candidate;
  return null;
}

// The first exported interface of a model's declaration file: its fields.
function declaration(file) {
  if (declarations.has(file)) return declarations.get(file);
  const text = readFileSync(file, "utf8");
  const imports = new Map();
  for (const m of text.matchAll(/import \{([^}]*)\} from "([^"]+)"/g))
    for (const name of m[1].split(",").map((s) => s.trim().split(/\s+as\s+/).pop()))
      if (name) imports.set(name, resolveImport(file, m[2]));
  const body = text.match(/export interface \w+[^{]*\{([\s\S]*?)\n\}/);
  const props = new Map();
  if (body)
    // Fields sit at one indentation; a map's type ("{ [key: string]: ... }")
    // spans several lines and is kept as its first.
    for (const m of body[1].matchAll(/^ {4}"([^"]+)"\??: (.*)$/gm)) props.set(m[1], m[2].trim().replace(/;$/, ""));
  const d = { props, imports, file };
  declarations.set(file, d);
  return d;
}

// Walks `value` along declaration `d`; pushes "path: unknown field" problems.
function checkFields(value, d, where, problems) {
  if (!d || value === null || typeof value !== "object" || Array.isArray(value)) return;
  if (d.props.size === 0) return; // an open map or a type without fields
  for (const [key, child] of Object.entries(value)) {
    const type = d.props.get(key);
    if (type === undefined) {
      problems.push(`${where}: unknown field '${key}' (known: ${[...d.props.keys()].join(", ")})`);
      continue;
    }
    const array = type.match(/^Array<(\w+)>$/);
    const named = array ? array[1] : type.match(/^(\w+)$/)?.[1];
    const file = named ? d.imports.get(named) : null;
    if (!file) continue; // a primitive, a map, a union: the schema validator covers it
    const childDecl = declaration(file);
    if (array && Array.isArray(child)) child.forEach((item, i) => checkFields(item, childDecl, `${where}.${key}[${i}]`, problems));
    else if (!array) checkFields(child, childDecl, `${where}.${key}`, problems);
  }
}

// --- Documents -------------------------------------------------------------

function validateDocument(object, where, file) {
  const problems = [];
  if (object === null || typeof object !== "object" || Array.isArray(object))
    return [`${where}: not a mapping`];
  const { apiVersion, kind } = object;
  if (typeof apiVersion !== "string" || typeof kind !== "string") return [`${where}: no apiVersion or kind`];
  if (`${apiVersion}/${kind}` === KUSTOMIZATION) {
    for (const resource of object.resources ?? [])
      if (!existsSync(path.resolve(path.dirname(file), resource)))
        problems.push(`${where}: resource ${resource} does not exist`);
    return problems;
  }
  const modelFile = path.join(modelsRoot, apiVersion, `${kind}.js`);
  if (!existsSync(modelFile)) return [`${where}: ${apiVersion} ${kind} is not a Kubernetes API kind`];
  const Model = require(modelFile)[kind];
  try {
    new Model(object).validate();
  } catch (error) {
    problems.push(`${where}: ${error.message}`);
  }
  checkFields(object, declaration(modelFile.replace(/\.js$/, ".d.ts")), where, problems);
  const name = object.metadata?.name;
  if (typeof name !== "string" || !/^[a-z0-9]([-a-z0-9]*[a-z0-9])?$/.test(name) || name.length > 63)
    problems.push(`${where}: metadata.name '${name}' is not a DNS label`);
  return problems;
}

const files = process.argv.slice(2);
if (files.length === 0) {
  console.error("usage: node validate.mjs MANIFEST.yaml...");
  process.exit(2);
}
let problems = [];
let count = 0;
for (const file of files) {
  const documents = YAML.parseAllDocuments(readFileSync(file, "utf8"));
  documents.forEach((doc, i) => {
    const where = `${path.basename(file)}#${i + 1}`;
    if (doc.errors.length > 0) {
      problems.push(...doc.errors.map((e) => `${where}: ${e.message}`));
      return;
    }
    const object = doc.toJS();
    if (object === null) return; // an empty document
    const kind = object?.kind ?? "?";
    problems.push(...validateDocument(object, `${where} (${kind} ${object?.metadata?.name ?? ""})`.trim(), file));
    ++count;
  });
}
for (const p of problems) console.log(`INVALID ${p}`);
console.log(`${count} document(s) in ${files.length} file(s): ${problems.length} problem(s)`);
process.exit(problems.length === 0 ? 0 : 1);
