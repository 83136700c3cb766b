// Generates the page's and the gateway's TypeScript/JavaScript API code from proto/loomlight/v1/loomlight.proto
// (protoc, Debian's, with @bufbuild/protoc-gen-es from this package's lock file) into web/gen/: never committed,
// made again by every build (npm run build, scripts/serve.sh, scripts/test.sh).
import { execFileSync } from "node:child_process";
import { mkdirSync, rmSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

const web = join(dirname(fileURLToPath(import.meta.url)), "..");
const out = join(web, "gen");
rmSync(out, { recursive: true, force: true });
mkdirSync(out, { recursive: true });
execFileSync("protoc", [
  `--proto_path=${join(web, "..", "proto")}`,
  `--plugin=protoc-gen-es=${join(web, "node_modules", ".bin", "protoc-gen-es")}`,
  `--es_out=${out}`,
  // JavaScript with declarations: node runs the gateway without a compiler, Vite bundles the page with types.
  "--es_opt=target=js+dts,import_extension=js",
  "loomlight/v1/loomlight.proto",
  "grpc/health/v1/health.proto",
], { stdio: "inherit" });
