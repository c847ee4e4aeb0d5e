// The asset page: live cards (polling GET /assets), uploads with progress, and a detail view
// with render controls, drag-to-turn from a turntable, the render plan in words, download and
// delete. Plain browser APIs only: it works offline.
"use strict";
const DEFAULTS = JSON.parse(document.getElementById("defaults").textContent);
const $ = id => document.getElementById(id);
const cards = new Map();      // asset id -> {el, rec}
let current = null;           // asset record shown in the detail view
let frames = null;            // turntable ImageBitmaps of the detail view, with their yaws
let stillUrl = null;
const POLL_MS = 1500, TURNTABLE_FRAMES = 24;

// The key lives in this tab's sessionStorage and goes as a bearer header, never as a cookie
// (a cookie would go along with another site's requests too).
function authHeaders() {
  const key = $("key").value || sessionStorage.getItem("apiKey") || "";
  return key ? {Authorization: "Bearer " + key} : {};
}
$("key").value = sessionStorage.getItem("apiKey") || "";
$("key").onchange = () => { sessionStorage.setItem("apiKey", $("key").value); poll(); };

async function errorText(r) {
  try { const body = await r.json(); return `error ${r.status}: ${typeof body.detail === "string" ? body.detail : JSON.stringify(body.detail)}`; }
  catch { return `error ${r.status} ${r.statusText}`; }
}

// --- cards ------------------------------------------------------------------------------------
function card(rec) {
  let c = cards.get(rec.id);
  if (!c) {
    const el = document.createElement("figure");
    el.className = "card";
    el.dataset.id = rec.id;
    el.innerHTML = `<div class="placeholder">baking…</div><figcaption><span><span class="name"></span><br><small class="note"></small></span><span class="status"></span></figcaption>`;
    el.onclick = () => openDetail(cards.get(rec.id).rec);
    $("grid").appendChild(el);
    c = {el, rec: null};
    cards.set(rec.id, c);
  }
  const old = c.rec;
  c.rec = rec;
  const el = c.el;
  el.dataset.status = rec.status;
  el.querySelector(".name").textContent = rec.name;
  el.querySelector(".note").textContent = rec.status === "failed" ? (rec.reason || "failed") : `${rec.triangles.toLocaleString()} triangles`;
  const status = el.querySelector(".status");
  status.textContent = rec.status;
  status.className = "status status-" + rec.status;
  if (rec.status === "ready" && (!old || old.status !== "ready")) {
    const img = document.createElement("img");
    img.alt = rec.name;
    el.querySelector(".placeholder, img").replaceWith(img);
    loadThumbnail(img, `${rec.thumbnail}?size=256`);
  } else if (rec.status === "failed") {
    el.querySelector(".placeholder, img").textContent = "failed";
  }
}

// Fetched (not <img src>) so the API key goes along when the server wants one for reads too.
async function loadThumbnail(img, url) {
  for (let tries = 0; tries < 20; tries++) {
    try {
      const r = await fetch(url, {headers: authHeaders()});
      if (r.ok) { img.src = URL.createObjectURL(await r.blob()); return; }
      if (r.status !== 202) { img.alt = await errorText(r); return; }
    } catch { /* network: try again */ }
    await new Promise(res => setTimeout(res, 2000));
  }
}

async function poll() {
  try {
    const r = await fetch("/assets", {cache: "no-store", headers: authHeaders()});
    if (r.status === 401) {  // the page is open, the data is not: ask for the key here
      $("msg").textContent = "this server needs its API key: enter it in the key field";
      $("key").classList.add("wanted");
      return;
    }
    if (!r.ok) throw new Error(await errorText(r));
    $("key").classList.remove("wanted");
    if ($("msg").textContent.startsWith("this server needs") || $("msg").textContent.startsWith("cannot list")) $("msg").textContent = "";
    const {assets} = await r.json();
    const seen = new Set(assets.map(a => a.id));
    assets.forEach(card);
    for (const [id, c] of cards) if (!seen.has(id)) { c.el.remove(); cards.delete(id); }
    $("count").textContent = assets.length;
  } catch (e) {
    $("msg").textContent = "cannot list assets: " + e.message;
  }
}
setInterval(poll, POLL_MS);
poll();

// --- upload -----------------------------------------------------------------------------------
// A zip with several entry points is answered 422 with `candidates`: the page offers them in the
// form's `main` field, and the next upload names the one chosen.
function offerEntryPoints(candidates) {
  const select = $("main");
  select.replaceChildren(...candidates.map(c => new Option(c, c)));
  select.hidden = candidates.length === 0;
}
$("file").onchange = () => offerEntryPoints([]);

$("upload").onsubmit = e => {
  e.preventDefault();
  const file = $("file").files[0];
  if (!file) return;
  const xhr = new XMLHttpRequest(), bar = $("progress"), msg = $("msg");
  xhr.open("POST", "/assets");
  for (const [k, v] of Object.entries(authHeaders())) xhr.setRequestHeader(k, v);
  xhr.upload.onprogress = ev => { if (ev.lengthComputable) bar.value = ev.loaded / ev.total; msg.textContent = `uploading ${Math.round(100 * bar.value)}%`; };
  xhr.onload = () => {
    bar.hidden = true;
    let body = null;
    try { body = JSON.parse(xhr.responseText); } catch { /* not JSON: reported below */ }
    if (xhr.status === 200 || xhr.status === 201) {
      msg.textContent = `${body.name}: ${xhr.status === 201 ? "uploaded, " + body.status : "already here"}`;
      card(body);
      $("upload").reset();
      offerEntryPoints([]);
    } else if (xhr.status === 422 && body && Array.isArray(body.candidates) && body.candidates.length) {
      offerEntryPoints(body.candidates);
      msg.textContent = `${file.name} holds ${body.candidates.length} entry points: choose one, then Upload`;
    } else {
      const detail = body && body.detail ? (typeof body.detail === "string" ? body.detail : JSON.stringify(body.detail)) : xhr.statusText;
      msg.textContent = `error ${xhr.status}: ${detail}`;
    }
  };
  xhr.onerror = () => { bar.hidden = true; msg.textContent = "error: the upload did not reach the server (network)"; };
  xhr.ontimeout = () => { bar.hidden = true; msg.textContent = "error: the upload timed out"; };
  bar.hidden = false; bar.value = 0; msg.textContent = "uploading 0%";
  xhr.send(new FormData($("upload")));
};

// --- detail view ------------------------------------------------------------------------------
const controls = ["env", "yaw", "pitch", "method", "size", "background", "shadow"];

async function loadEnvironments() {
  const sel = $("c-env");
  if (sel.options.length) return;
  try {
    const r = await fetch("/environments", {headers: authHeaders()});
    const {environments} = await r.json();
    for (const e of environments) sel.add(new Option(e.name, e.name, e.default, e.default));
  } catch (e) { $("d-error").textContent = "cannot list environments: " + e.message; }
}

function query(extra = {}) {
  const p = new URLSearchParams();
  for (const name of controls) p.set(name, $("c-" + name).value);
  for (const [k, v] of Object.entries(extra)) p.set(k, v);
  return p;
}

// Each kind of request (the still, the turntable) has one in flight at most: a new one aborts
// the old, and a response is shown only while its request is still the latest of its kind for
// the asset on view, so a slow old answer never overwrites a newer one.
const inflight = {still: null, turntable: null, estimate: null};

function begin(kind) {
  if (inflight[kind]) inflight[kind].abort();
  const ctl = new AbortController();
  inflight[kind] = ctl;
  const rec = current;
  return {signal: ctl.signal, latest: () => inflight[kind] === ctl && current === rec && !ctl.signal.aborted};
}

function abortAll() {
  for (const kind of Object.keys(inflight)) { if (inflight[kind]) inflight[kind].abort(); inflight[kind] = null; }
}

function resetControls() {
  // Every control back to its default: DEFAULTS (the server's, from core.options), else the page's own.
  for (const name of controls) {
    const el = $("c-" + name);
    if (name in DEFAULTS && name !== "size") { el.value = DEFAULTS[name]; continue; }
    if (el.tagName === "SELECT") {
      const d = [...el.options].find(o => o.defaultSelected) || el.options[0];
      if (d) el.value = d.value;
    } else el.value = el.defaultValue;
  }
}

async function openDetail(rec) {
  abortAll();
  current = rec;
  frames = null;
  $("d-name").textContent = rec.name;
  $("d-name").title = rec.name;
  $("d-info").textContent = `${rec.format} · ${rec.triangles.toLocaleString()} triangles · ${rec.materials} materials · ${rec.status}`;
  $("d-error").textContent = rec.status === "failed" ? "bake failed: " + (rec.reason || "") : "";
  $("d-plan").textContent = "";
  $("d-cost").textContent = "";
  $("c-method").querySelector("option[value=raytrace]").textContent = "raytrace";
  $("d-plan").classList.remove("stale");
  $("canvas").dataset.state = "empty";
  delete $("canvas").dataset.frames;
  $("d-stale").hidden = true;
  $("hint").textContent = "drag to turn";
  const c = $("canvas");
  c.getContext("2d").clearRect(0, 0, c.width, c.height);
  $("d-download").removeAttribute("href");
  // Open before any await: a dialog's close event fires later than close() itself, so one
  // still queued from closing the previous asset must find the dialog open (onclose) and
  // leave this asset's requests alone.
  if (!$("detail").open) $("detail").showModal();
  await loadEnvironments();
  if (current !== rec) return;
  resetControls();
  showOutputs();
  if (rec.status !== "failed") { renderStill(); loadTurntable(); updateCost(); }
}

function showOutputs() {
  $("o-yaw").textContent = $("c-yaw").value + "°";
  $("o-pitch").textContent = $("c-pitch").value + "°";
  $("o-shadow").textContent = $("c-shadow").value;
}

function sleep(ms, signal) {
  return new Promise((res, rej) => {
    const t = setTimeout(res, ms);
    signal.addEventListener("abort", () => { clearTimeout(t); rej(new DOMException("aborted", "AbortError")); }, {once: true});
  });
}

async function fetchImage(params, req) {
  // 202: still baking; try again after Retry-After.
  for (let tries = 0; tries < 60; tries++) {
    const r = await fetch(`/assets/${current.id}/thumbnail?${params}`, {headers: authHeaders(), signal: req.signal});
    if (r.status === 202) {
      if (req.latest()) $("d-plan").textContent = "baking… the image follows when the bake is done";
      await sleep(1000 * (+r.headers.get("Retry-After") || 2), req.signal);
      continue;
    }
    if (!r.ok) throw new Error(await errorText(r));
    return r;
  }
  throw new Error("still baking after a minute");
}

async function renderStill() {
  const rec = current, params = query(), req = begin("still");
  $("canvas").dataset.state = "loading";
  try {
    const r = await fetchImage(params, req);
    const blob = await r.blob();
    const bitmap = await createImageBitmap(blob);
    if (!req.latest()) return;
    draw(bitmap);
    $("d-error").textContent = "";  // errors belong to the request that caused them
    $("d-stale").hidden = true;
    $("d-plan").classList.remove("stale");
    $("d-plan").textContent = planInWords(r.headers.get("X-Render-Plan"));
    if (stillUrl) URL.revokeObjectURL(stillUrl);
    stillUrl = URL.createObjectURL(blob);
    $("d-download").href = stillUrl;
    $("d-download").download = `${rec.name.replace(/\.[^.]*$/, "")}-yaw${params.get("yaw")}.png`;
    $("canvas").dataset.state = "ready";
  } catch (e) {
    if (e.name === "AbortError" || !req.latest()) return;
    $("d-error").textContent = e.message;
    $("canvas").dataset.state = "error";
    // What is still drawn (if anything) is not what was asked for: say so over it.
    const shown = !!$("d-download").getAttribute("href");
    $("d-stale").textContent = shown ? "not updated: this request was refused (see below); the image and plan are of the previous settings" : "refused: see below";
    $("d-stale").hidden = false;
    if (shown) $("d-plan").classList.add("stale");
  }
}

function seconds(ms) { return ms < 1000 ? `${Math.round(ms)} ms` : `${(ms / 1000).toFixed(ms < 10000 ? 1 : 0)} s`; }

async function updateCost() {
  // What method=raytrace costs at these settings, by the service's own estimator (the model it
  // admits renders with), shown before anyone waits for one; and whether it would be refused.
  const req = begin("estimate"), opt = $("c-method").querySelector("option[value=raytrace]");
  try {
    const r = await fetch(`/assets/${current.id}/estimate?${query({method: "raytrace"})}`, {headers: authHeaders(), signal: req.signal});
    if (!r.ok) throw new Error(await errorText(r));
    const e = await r.json();
    if (!req.latest()) return;
    const cost = e.cached ? "cached" : "≈ " + seconds(e.estimated_ms);
    opt.textContent = `raytrace (${cost}${e.refused ? ", refused here" : ""})`;
    $("d-cost").textContent = e.cached ? "raytrace at these settings: cached, served at once"
      : `raytrace at these settings: ≈ ${seconds(e.estimated_ms)} estimated` +
        (e.refused ? `, ${e.refused.replace(/\d+ ms/, seconds(e.ceiling_ms))}: it would be refused` : "");
    $("d-cost").dataset.refused = e.refused ? "1" : "";
  } catch (err) {
    if (err.name === "AbortError" || !req.latest()) return;
    opt.textContent = "raytrace";
    $("d-cost").textContent = "raytrace cost unknown: " + err.message;
  }
}

function draw(bitmap) {
  const c = $("canvas"), g = c.getContext("2d");
  c.width = bitmap.width; c.height = bitmap.height;
  g.clearRect(0, 0, c.width, c.height);
  g.drawImage(bitmap, 0, 0);
}

async function loadTurntable() {
  // One animated WebP (one request, one upload of the asset on the server), decoded frame by
  // frame with the browser's ImageDecoder; without it, dragging re-renders at the new yaw.
  frames = null;  // the old frames show the old settings: none until the new ones are in
  delete $("canvas").dataset.frames;
  if (!("ImageDecoder" in window)) { $("hint").textContent = "drag to turn (re-renders)"; return; }
  const req = begin("turntable");
  const size = Math.min(+$("c-size").value, 512);
  const yaw0 = +$("c-yaw").value;
  const params = query({turntable: TURNTABLE_FRAMES, format: "webp", size, yaw: yaw0});
  $("hint").textContent = "drag to turn (re-renders until the turntable is in)";
  try {
    const r = await fetchImage(params, req);
    const decoder = new ImageDecoder({data: r.body, type: "image/webp"});
    await decoder.completed;  // all bytes in: the frame count is final
    const n = decoder.tracks.selectedTrack.frameCount;
    const list = [];
    for (let i = 0; i < n; i++) list.push(await createImageBitmap((await decoder.decode({frameIndex: i})).image));
    if (!req.latest()) return;
    frames = {bitmaps: list, yaw0};
    $("hint").textContent = `drag to turn (${n} frames)`;
    $("canvas").dataset.frames = n;
  } catch (e) {
    if (e.name === "AbortError" || !req.latest()) return;
    $("hint").textContent = "drag to turn (re-renders): " + e.message;
  }
}

let drag = null;
$("canvas").onpointerdown = e => { drag = {x: e.clientX, step: 0}; $("canvas").setPointerCapture(e.pointerId); };
$("canvas").onpointermove = e => {
  if (!drag) return;
  const dx = e.clientX - drag.x, w = $("canvas").clientWidth;
  if (frames) {
    // Frame 0 is at the turntable's yaw; the still may have turned since (a drag, the slider).
    const n = frames.bitmaps.length, offset = Math.round((+$("c-yaw").value - frames.yaw0) / 360 * n);
    drag.step = Math.round(-dx / w * n);
    const frame = (((offset + drag.step) % n) + n) % n;
    draw(frames.bitmaps[frame]);
    $("canvas").dataset.frame = frame;
  }
  drag.degrees = -dx / w * 360;
};
$("canvas").onpointerup = () => {
  if (!drag) return;
  const turned = frames ? drag.step * 360 / frames.bitmaps.length : (drag.degrees || 0);
  drag = null;
  if (!turned) return;
  let yaw = ((+$("c-yaw").value + turned + 180) % 360 + 360) % 360 - 180;
  $("c-yaw").value = Math.round(yaw / 5) * 5;
  showOutputs();
  renderStill();
};

$("controls").oninput = showOutputs;
$("controls").onchange = e => {
  renderStill();
  // The turntable starts at the yaw, so only other controls make its frames stale.
  if (e.target.id !== "c-yaw") { loadTurntable(); updateCost(); }
};
$("controls").onsubmit = e => e.preventDefault();
$("d-close").onclick = () => $("detail").close();
$("detail").onclose = () => { if (!$("detail").open) { abortAll(); current = null; } };
$("d-delete").onclick = async () => {
  const rec = current;
  if (!confirm(`Delete ${rec.name}?`)) return;
  let r = await fetch(`/assets/${rec.id}`, {method: "DELETE", headers: authHeaders()});
  if (r.status === 401) {  // the key field is under this dialog: ask for it here
    const key = prompt("This server needs its API key to delete:");
    if (key) {
      $("key").value = key;
      sessionStorage.setItem("apiKey", key);
      r = await fetch(`/assets/${rec.id}`, {method: "DELETE", headers: authHeaders()});
    }
  }
  if (!r.ok) { $("d-error").textContent = await errorText(r); return; }
  $("detail").close();
  const c = cards.get(rec.id);
  if (c) { c.el.remove(); cards.delete(rec.id); }
  $("msg").textContent = `${rec.name} deleted`;
  poll();
};

// --- the render plan (X-Render-Plan) in words ------------------------------------------------
function planInWords(header) {
  if (!header) return "";
  let p;
  try { p = JSON.parse(header); } catch { return header; }
  const lines = [];
  const objs = (p.auto && p.auto.objects) || p.objects || [];
  lines.push(`Method ${p.method}${p.auto && p.auto.request ? ": " + p.auto.request : ""}.`);
  objs.slice(0, 4).forEach(o => lines.push(`${o.mesh}${o.count > 1 ? ` and ${o.count - 1} more` : ""}: ${o.method} (${o.why}).`));
  if (objs.length > 4) lines.push(`…and ${objs.length - 4} more objects.`);
  if (p.environment) lines.push(`Lit by ${p.environment}; background ${p.background}; tone map ${p.tonemap}.`);
  if (p.shadow) lines.push(`Ground shadow: ${p.shadow}.`);
  if (p.view) lines.push(`Seen from yaw ${p.view.yaw}°, pitch ${p.view.pitch}°${p.msaa ? `, ${p.msaa}x MSAA` : ""}.`);
  if (p.lights) lines.push(`${p.lights} light${p.lights > 1 ? "s" : ""} from the asset.`);
  return lines.join("\n");
}
