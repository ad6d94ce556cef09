// Checks that deploy/k8s/ and deploy/docker-compose.yml describe the same
// deployment: the same images, command-line flags, ports, memory limits and
// health endpoints, the SMA finding the renderers through a headless
// Service, and the autoscaler scaling the renderers on the SMA's metric.
//
//   node consistency.mjs RESOLVED_COMPOSE.yaml K8S_DIR
//
// RESOLVED_COMPOSE.yaml: `docker-compose config` output with the defaults.
// Packages as in validate.mjs ($PENUMBRA_K8S_NODE_MODULES).

import { readFileSync, readdirSync } from "node:fs";
import { createRequire } from "node:module";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const modules = process.env.PENUMBRA_K8S_NODE_MODULES || path.join(here, "node_modules");
const YAML = createRequire(path.join(modules, "noop.js"))("yaml");

const [composeFile, k8sDir] = process.argv.slice(2);
if (!composeFile || !k8sDir) {
  console.error("usage: node consistency.mjs RESOLVED_COMPOSE.yaml K8S_DIR");
  process.exit(2);
}
const compose = YAML.parse(readFileSync(composeFile, "utf8"));
const objects = [];
for (const file of readdirSync(k8sDir).filter((f) => f.endsWith(".yaml")).sort())
  for (const doc of YAML.parseAllDocuments(readFileSync(path.join(k8sDir, file), "utf8"))) {
    const o = doc.toJS();
    if (o && o.kind !== "Kustomization") objects.push(o);
  }

const problems = [];
const fail = (message) => problems.push(message);
const find = (kind, name) => objects.find((o) => o.kind === kind && o.metadata?.name === name);
const flag = (args, name) => args.find((a) => a.startsWith(`--${name}=`))?.slice(name.length + 3);
const portOf = (address) => Number(address?.split(":").pop());

// "4g" (compose) and "4Gi" (Kubernetes) are the same amount.
function bytes(quantity) {
  const m = String(quantity).match(/^(\d+(?:\.\d+)?)\s*([a-zA-Z]*)$/);
  if (!m) return NaN;
  const unit = { "": 1, b: 1, k: 1024, ki: 1024, m: 1024 ** 2, mi: 1024 ** 2, g: 1024 ** 3, gi: 1024 ** 3 }[m[2].toLowerCase()];
  return unit ? Number(m[1]) * unit : NaN;
}

// One tier: the workload's single container against the compose service.
function checkTier(tier, kind, workloadName, renameArgs = (a) => a) {
  const service = compose.services?.[tier];
  const workload = find(kind, workloadName);
  if (!service) return fail(`compose has no service '${tier}'`);
  if (!workload) return fail(`deploy/k8s has no ${kind} ${workloadName}`);
  const containers = workload.spec.template.spec.containers;
  if (containers.length !== 1) return fail(`${workloadName}: expected one container, found ${containers.length}`);
  const c = containers[0];
  if (c.image !== service.image) fail(`${workloadName}: image ${c.image}, compose has ${service.image}`);
  const expected = service.command.map(renameArgs);
  if (JSON.stringify(c.args) !== JSON.stringify(expected))
    fail(`${workloadName}: args ${JSON.stringify(c.args)}\n  differ from compose's ${JSON.stringify(expected)}`);
  const wirePort = portOf(flag(c.args ?? [], "listen"));
  const httpPort = portOf(flag(c.args ?? [], "http"));
  if (!httpPort) fail(`${workloadName}: no --http flag, so no probes or metrics`);
  const named = Object.fromEntries((c.ports ?? []).map((p) => [p.name, p.containerPort]));
  if (named.wire !== wirePort) fail(`${workloadName}: container port 'wire' is ${named.wire}, --listen says ${wirePort}`);
  if (named.http !== httpPort) fail(`${workloadName}: container port 'http' is ${named.http}, --http says ${httpPort}`);
  const probePort = (p) => (p?.httpGet?.port === "http" ? httpPort : p?.httpGet?.port);
  if (c.readinessProbe?.httpGet?.path !== "/readyz" || probePort(c.readinessProbe) !== httpPort)
    fail(`${workloadName}: the readiness probe must GET /readyz on the --http port`);
  if (c.livenessProbe?.httpGet?.path !== "/healthz" || probePort(c.livenessProbe) !== httpPort)
    fail(`${workloadName}: the liveness probe must GET /healthz on the --http port`);
  // Compose's health check asks the same endpoint.
  const test = service.healthcheck?.test ?? [];
  if (!(test.includes("--ready") && test.at(-1) === `127.0.0.1:${httpPort}`))
    fail(`${tier} (compose): the health check ${JSON.stringify(test)} is not /readyz on ${httpPort}`);
  // Published ports resolve to "HOST:PUBLISHED:TARGET/tcp" (or {target}).
  const target = (p) => Number(typeof p === "object" ? p.target : String(p).split("/")[0].split(":").pop());
  const exposed = (service.expose ?? []).map(Number).concat((service.ports ?? []).map(target));
  for (const port of [wirePort, httpPort])
    if (!exposed.includes(port)) fail(`${tier} (compose): port ${port} is neither exposed nor published`);
  const composeMemory = bytes(service.deploy?.resources?.limits?.memory);
  const k8sMemory = bytes(c.resources?.limits?.memory);
  if (composeMemory !== k8sMemory)
    fail(`${workloadName}: memory limit ${c.resources?.limits?.memory}, compose has ${service.deploy?.resources?.limits?.memory}`);
  if (!c.resources?.requests?.cpu || !c.resources?.requests?.memory)
    fail(`${workloadName}: no cpu and memory requests`);
  const annotations = workload.spec.template.metadata?.annotations ?? {};
  if (annotations["prometheus.io/port"] !== String(httpPort))
    fail(`${workloadName}: prometheus.io/port annotation is not the --http port ${httpPort}`);
  return { workload, container: c, wirePort, httpPort };
}

// The Service of a workload's pods, by selector.
function servicesFor(workload) {
  const labels = workload.spec.template.metadata?.labels ?? {};
  return objects.filter(
    (o) => o.kind === "Service" && Object.entries(o.spec.selector ?? {}).every(([k, v]) => labels[k] === v) && o.spec.selector,
  );
}

const rendererHost = flag(compose.services?.sma?.command ?? [], "renderer")?.split(":")[0];
const rendererService = objects.find((o) => o.kind === "Service" && o.metadata.name === "penumbra-renderer");
const renderer = checkTier("renderer", "Deployment", "penumbra-renderer");
// The SMA's --renderer names compose's service `renderer`; in Kubernetes the
// renderers' headless Service.
const sma = checkTier("sma", "StatefulSet", "penumbra-sma", (arg) =>
  arg === `--renderer=${rendererHost}:${portOf(flag(compose.services.sma.command, "renderer"))}`
    ? `--renderer=${rendererService?.metadata.name}:${portOf(flag(compose.services.sma.command, "renderer"))}`
    : arg,
);

if (renderer?.workload) {
  if (!rendererService) fail("no Service penumbra-renderer for the SMA to resolve");
  else {
    if (rendererService.spec.clusterIP !== "None")
      fail("Service penumbra-renderer must be headless (clusterIP: None): the SMA connects to every renderer");
    if (!servicesFor(renderer.workload).includes(rendererService))
      fail("Service penumbra-renderer does not select the renderer pods");
    const wire = rendererService.spec.ports.find((p) => p.port === renderer.wirePort);
    if (!wire) fail(`Service penumbra-renderer has no port ${renderer.wirePort}`);
  }
  if (compose.services.renderer.deploy?.endpoint_mode !== "dnsrr")
    fail("compose's renderer service should resolve to every replica (endpoint_mode: dnsrr), as the headless Service does");
  if (renderer.workload.spec.replicas !== compose.services.renderer.deploy?.replicas)
    fail(`renderer replicas ${renderer.workload.spec.replicas}, compose has ${compose.services.renderer.deploy?.replicas}`);
}
if (sma?.workload) {
  const smaArgs = sma.container.args;
  if (flag(smaArgs, "renderer") !== `penumbra-renderer:${renderer?.wirePort}`)
    fail(`the SMA's --renderer ${flag(smaArgs, "renderer")} is not the headless Service penumbra-renderer:${renderer?.wirePort}`);
  const forClients = find("Service", "penumbra-sma");
  if (!forClients) fail("no Service penumbra-sma for clients");
  else {
    if (!servicesFor(sma.workload).includes(forClients)) fail("Service penumbra-sma does not select the SMA pod");
    if (!forClients.spec.ports.some((p) => p.port === sma.wirePort))
      fail(`Service penumbra-sma does not offer the client port ${sma.wirePort}`);
  }
  if (!find("Service", sma.workload.spec.serviceName))
    fail(`the StatefulSet's serviceName ${sma.workload.spec.serviceName} is no Service here`);
  if (compose.services.client?.command?.includes(`--connect=sma:${sma.wirePort}`) !== true)
    fail(`compose's client does not connect to the SMA's port ${sma.wirePort}`);
}

const hpa = objects.find((o) => o.kind === "HorizontalPodAutoscaler");
if (!hpa) fail("no HorizontalPodAutoscaler for the renderers");
else {
  const target = hpa.spec.scaleTargetRef;
  if (target.kind !== "Deployment" || target.name !== "penumbra-renderer")
    fail(`the autoscaler scales ${target.kind} ${target.name}, not the renderer Deployment`);
  const metric = hpa.spec.metrics?.[0]?.external?.metric?.name;
  if (metric !== "penumbra_sma_samples_queued")
    fail(`the autoscaler reads '${metric}', not the SMA's penumbra_sma_samples_queued`);
  if (!(hpa.spec.minReplicas >= 1 && hpa.spec.maxReplicas >= hpa.spec.minReplicas))
    fail("the autoscaler's replica range is empty");
}

for (const p of problems) console.log(`INCONSISTENT ${p}`);
console.log(`compose and deploy/k8s: ${problems.length} inconsistenc${problems.length === 1 ? "y" : "ies"}`);
process.exit(problems.length === 0 ? 0 : 1);
