// A screenshot of Loomlight Studio for a material, as a designer sees it once every view has settled: a gateway
// of its own (port 0) in front of the server named, Debian's chromium headless.
//   node web/scripts/screenshot.mjs --server HOST:PORT --out FILE.png [--model NAME] [--preset NAME]
//                                  [--size WIDTHxHEIGHT]   (default $LOOMLIGHT_SERVER, the first model's preset,
//                                                          1280x800)
import { parseArgs } from "node:util";
import { launchBrowser, startGateway, viewsSettled } from "../tests/harness.mjs";

const { values } = parseArgs({
  options: {
    server: { type: "string", default: process.env.LOOMLIGHT_SERVER ?? "127.0.0.1:50051" },
    out: { type: "string" },
    model: { type: "string" },
    preset: { type: "string" },
    size: { type: "string", default: "1280x800" },
  },
});
const size = /^(\d+)x(\d+)$/.exec(values.size);
if (!values.out || !size) {
  console.error("usage: node web/scripts/screenshot.mjs --server HOST:PORT --out FILE.png [--model NAME] " +
                "[--preset NAME] [--size WIDTHxHEIGHT]");
  process.exit(2);
}
const gateway = await startGateway({ target: values.server });
const browser = await launchBrowser();
let status = 0;
try {
  const page = await browser.newPage({ viewport: { width: Number(size[1]), height: Number(size[2]) } });
  await page.goto(gateway.url);
  await viewsSettled(page, ["#lobe"], false);
  for (const [select, value] of [["#model", values.model], ["#preset", values.preset]]) {
    if (!value) continue;
    const options = await page.$$eval(`${select} option`, (list) => list.map((o) => o.value));
    if (!options.includes(value)) throw new Error(`${select.slice(1)}: no '${value}' (${options.join(", ")})`);
    await page.selectOption(select, value);
  }
  await viewsSettled(page, ["#lobe", "#halfdiff", "#sphere", "#slice"]);
  await page.screenshot({ path: values.out });
  console.log(`wrote ${values.out} (${values.size})`);
} catch (error) {
  console.error(`screenshot: ${error.message.split("\n")[0]}`);
  status = 1;
} finally {
  await browser.close();
  await gateway.stop();
}
process.exit(status);
