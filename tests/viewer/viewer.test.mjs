// Drives `ins-cli view` in headless Chromium: the page loads and renders, a drag changes the
// picture, a style slider changes its colours, the save button writes a PNG. Prints one JSON
// line of measurements; exits non-zero (with the reason) when any step fails.
// Usage: node viewer.test.mjs URL
import { chromium } from "playwright-core";

const url = process.argv[2];
const shots = process.argv[3]; // optional folder for the pictures seen
if (!url) throw new Error("usage: node viewer.test.mjs URL [FOLDER]");
const executablePath = process.env.CHROMIUM || "/usr/bin/chromium";
const browser = await chromium.launch({
  executablePath,
  args: ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"],
});
// Waits poll on a timer. Playwright's default polls in requestAnimationFrame, which headless
// Chromium can starve while other tests load the machine (one CI run timed out in such a wait).
const POLL = { polling: 100 };
const result = {};
let page = null;
try {
  page = await browser.newPage({ viewport: { width: 900, height: 600 } });
  page.setDefaultTimeout(120_000);
  const errors = [];
  page.on("pageerror", (e) => errors.push(e.message));

  // The picture's pixels, read through a canvas.
  const pixels = () => page.evaluate(() => {
    const img = document.getElementById("view");
    const c = document.createElement("canvas");
    c.width = img.naturalWidth; c.height = img.naturalHeight;
    const g = c.getContext("2d");
    g.drawImage(img, 0, 0);
    return Array.from(g.getImageData(0, 0, c.width, c.height).data);
  });
  const refined = async (previousSrc) => {
    await page.waitForFunction((prev) => {
      const img = document.getElementById("view");
      return img.dataset.rendered && img.dataset.rendered.startsWith("refined") && img.src !== prev && img.complete;
    }, previousSrc, POLL);
    return page.evaluate(() => document.getElementById("view").src);
  };
  // The share of pixels whose colour moved by more than 8/255 in some channel.
  const changed = (a, b) => {
    let n = 0;
    for (let i = 0; i < a.length; i += 4) {
      if (Math.max(Math.abs(a[i] - b[i]), Math.abs(a[i + 1] - b[i + 1]), Math.abs(a[i + 2] - b[i + 2])) > 8) n++;
    }
    return n / (a.length / 4);
  };
  const shot = async (name) => { if (shots) await page.locator("#view").screenshot({ path: `${shots}/${name}.png` }); };

  let t = Date.now();
  result.step = "first picture";
  await page.goto(url);
  await page.waitForFunction(() => {
    const img = document.getElementById("view");
    return (img.dataset.rendered || "").startsWith("coarse") && img.complete;
  }, undefined, POLL);
  result.first_coarse_ms = Date.now() - t;
  const coarseBox = await page.locator("#view").boundingBox();
  let src = await refined("");
  result.first_refined_ms = Date.now() - t;
  // The picture keeps its place and size on screen when the refined one replaces the coarse.
  const refinedBox = await page.locator("#view").boundingBox();
  result.box_moved_px = Math.max(...["x", "y", "width", "height"].map((k) => Math.abs(coarseBox[k] - refinedBox[k])));
  if (!(result.box_moved_px <= 1)) throw new Error(`the picture jumped on screen when refined (${JSON.stringify([coarseBox, refinedBox])})`);
  // Refine at 200 px from here on (the test's scene is small).
  result.step = "refined size 200";
  await page.locator("#quality").selectOption("200");
  src = await refined(src);
  const before = await pixels();
  await shot("before");

  // A drag orbits the camera: the picture changes.
  const box = await page.locator("#view").boundingBox();
  const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
  t = Date.now();
  result.step = "drag";
  await page.mouse.move(cx, cy);
  await page.mouse.down();
  await page.mouse.move(cx + 150, cy + 20, { steps: 5 });
  await page.mouse.up();
  src = await refined(src);
  result.drag_refined_ms = Date.now() - t;
  const dragged = await pixels();
  if (dragged.length !== before.length) throw new Error("the refined size changed after a drag");
  result.drag_change = changed(before, dragged);
  await shot("dragged");
  if (!(result.drag_change > 0.02)) throw new Error(`a drag did not change the picture (${result.drag_change})`);

  // A style slider: all weight to the second style.
  const sliders = await page.locator("#styles input[type=range]").count();
  result.sliders = sliders;
  if (sliders < 2) throw new Error(`expected a slider per style, found ${sliders}`);
  t = Date.now();
  result.step = "style slider";
  await page.locator("#mix-0").fill("0");
  await page.locator("#mix-1").fill("100");
  src = await refined(src);
  result.slider_refined_ms = Date.now() - t;
  const restyled = await pixels();
  result.slider_change = changed(dragged, restyled);
  await shot("restyled");
  if (!(result.slider_change > 0.02)) throw new Error(`the slider did not change the colours (${result.slider_change})`);

  // Depth and normals toggles give other pictures.
  for (const m of ["depth", "normals", "silhouette"]) {
    result.step = `mode ${m}`;
    await page.locator(`#mode-${m}`).check();
    src = await refined(src);
    result[`${m}_change`] = changed(restyled, await pixels());
    await shot(m);
  }
  await page.locator("#mode-color").check();
  src = await refined(src);

  // Save at a chosen size.
  result.step = "save";
  await page.locator("#save-size").fill("64x48");
  await page.locator("#save").click();
  await page.waitForFunction(() => document.getElementById("saved").dataset.path, undefined, POLL);
  result.saved = await page.evaluate(() => document.getElementById("saved").dataset.path);
  result.command = await page.evaluate(() => (document.querySelector("#saved code") || {}).textContent || null);
  if (errors.length) throw new Error("page errors: " + errors.join("; "));
  delete result.step;
  console.log(JSON.stringify(result));
} catch (e) {
  // What the page showed when the step failed: its status line and the picture's label.
  const page_state = page && await page.evaluate(() => {
    const img = document.getElementById("view");
    return {
      status: document.getElementById("status").textContent,
      rendered: img.dataset.rendered || null,
      natural: [img.naturalWidth, img.naturalHeight],
      complete: img.complete,
    };
  }).catch((err) => String(err));
  console.log(JSON.stringify({ ...result, error: String(e && e.message || e), page_state }));
  process.exitCode = 1;
} finally {
  await browser.close();
}
