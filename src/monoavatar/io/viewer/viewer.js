// monoavatar view: the page's script. Reads window.MONOAVATAR (see monoavatar/io/viewer_page.py
// for its fields), the glb and the key-frame atlas embedded in the page, and shows the avatar
// under orbit controls beside the input frames with the fitted avatar over them.
// Needs window.THREE (three.min.js, with GLTFLoader and OrbitControls). Settings may be given in
// the URL's hash: clip=NAME, t=SECONDS, paused=1, shading=albedo|shaded, heat=1, skeleton=1,
// layout=both|orbit|overlay, floor=0 (no grid), aa=0|1 (multisampling; default: on unless WebGL
// runs in software), lod=VERTICES (meshes larger than this move as a coarse stand-in; 60000),
// bench=FRAMES (render that many frames, report frames per second).
(function () {
  'use strict';
  const T = window.THREE;
  const DATA = window.MONOAVATAR;
  const BACKGROUND = 0x202428;
  const status = document.getElementById('status');

  function fail(message) {
    document.body.dataset.state = 'error';
    document.title = 'monoavatar view: error';
    status.textContent = 'error: ' + message;
    status.className = 'error';
  }
  window.addEventListener('error', (e) => fail(e.message));
  window.addEventListener('unhandledrejection', (e) => fail(String(e.reason)));

  function hashSettings() {
    const out = {};
    for (const part of window.location.hash.replace(/^#/, '').split('&')) {
      if (!part) continue;
      const [k, v] = part.split('=');
      out[decodeURIComponent(k)] = v === undefined ? '1' : decodeURIComponent(v);
    }
    return out;
  }

  function bytesOf(id) {
    const text = document.getElementById(id).textContent.trim();
    const raw = atob(text);
    const out = new Uint8Array(raw.length);
    for (let i = 0; i < raw.length; i++) out[i] = raw.charCodeAt(i);
    return out;
  }

  function parseGlb(bytes) {
    return new Promise((resolve, reject) => {
      new T.GLTFLoader().parse(bytes.buffer.slice(0), '', resolve, reject);
    });
  }

  function skinnedMeshOf(root) {
    let found = null;
    root.traverse((o) => { if (o.isSkinnedMesh && !found) found = o; });
    if (!found) throw new Error('the glb holds no skinned mesh');
    return found;
  }

  // A clip of window.MONOAVATAR → THREE.AnimationClip over the glb's joint nodes.
  function clipOf(spec, root) {
    const tracks = [];
    const rootBone = root.getObjectByName(spec.root);
    if (!rootBone) throw new Error('no joint named ' + spec.root + ' in the glb');
    const rest = rootBone.position;
    const position = [];
    for (const t of spec.translations) position.push(rest.x + t[0], rest.y + t[1], rest.z + t[2]);
    tracks.push(new T.VectorKeyframeTrack(spec.root + '.position', spec.times, position));
    for (const [joint, quats] of Object.entries(spec.rotations)) {
      tracks.push(new T.QuaternionKeyframeTrack(joint + '.quaternion', spec.times, quats));
    }
    return new T.AnimationClip(spec.name, spec.times[spec.times.length - 1], tracks);
  }

  function uprightMatrix() {
    const m = new T.Matrix4();
    const u = DATA.upright;
    m.set(u[0][0], u[0][1], u[0][2], 0, u[1][0], u[1][1], u[1][2], 0,
          u[2][0], u[2][1], u[2][2], 0, 0, 0, 0, 1);
    return m;
  }

  // The input's pinhole camera (OpenCV: world → camera x = R X + t, y down, z forward) as a
  // three.js camera (y up, looking down −z) with the projection of its intrinsics K.
  function inputCamera(cam) {
    const c = new T.PerspectiveCamera();
    const R = cam.R, t = cam.t, K = cam.K, w = cam.width, h = cam.height;
    const near = 0.05, far = 100.0;
    // camera → world: [Rᵀ·diag(1, −1, −1) | −Rᵀ t]
    const cx = [-(R[0][0] * t[0] + R[1][0] * t[1] + R[2][0] * t[2]),
                -(R[0][1] * t[0] + R[1][1] * t[1] + R[2][1] * t[2]),
                -(R[0][2] * t[0] + R[1][2] * t[1] + R[2][2] * t[2])];
    const m = new T.Matrix4();
    m.set(R[0][0], -R[1][0], -R[2][0], cx[0],
          R[0][1], -R[1][1], -R[2][1], cx[1],
          R[0][2], -R[1][2], -R[2][2], cx[2],
          0, 0, 0, 1);
    c.matrixAutoUpdate = false;
    c.matrix.copy(m);
    c.matrix.decompose(c.position, c.quaternion, c.scale);
    c.updateMatrixWorld(true);
    const p = new T.Matrix4();
    p.set(2 * K[0][0] / w, 0, 1 - 2 * K[0][2] / w, 0,
          0, 2 * K[1][1] / h, 2 * K[1][2] / h - 1, 0,
          0, 0, -(far + near) / (far - near), -2 * far * near / (far - near),
          0, 0, -1, 0);
    c.projectionMatrix.copy(p);
    c.projectionMatrixInverse.copy(p).invert();
    return c;
  }

  // Whether WebGL runs in software (SwiftShader, llvmpipe): multisampling there halves the
  // frame rate (docs/bench/2026-12-03-view-fps.md), so it is left off.
  function softwareWebgl() {
    const gl = document.createElement('canvas').getContext('webgl2');
    if (!gl) return true;
    const info = gl.getExtension('WEBGL_debug_renderer_info');
    const name = info ? String(gl.getParameter(info.UNMASKED_RENDERER_WEBGL)) : '';
    const lose = gl.getExtension('WEBGL_lose_context');
    if (lose) lose.loseContext();
    return /swiftshader|llvmpipe|software/i.test(name);
  }

  // A coarse stand-in for a large skinned mesh, drawn while it moves (playing, or the camera
  // being dragged): vertices clustered on a grid of cells (in position and, so that UV seams
  // stay apart, in texture space), each cluster kept as one of its vertices with its normal,
  // UV and skin; triangles that collapse are dropped. About ``target`` vertices; null for a
// mesh of ``threshold`` vertices or fewer.
  function proxyOf(mesh, threshold, target) {
    const g = mesh.geometry, P = g.attributes.position, n = P.count;
    if (n <= threshold) return null;
    g.computeBoundingBox();
    const size = new T.Vector3();
    g.boundingBox.getSize(size);
    const area = 2 * (size.x * size.y + size.y * size.z + size.z * size.x);
    const cell = Math.sqrt(area / target) * 0.6;
    const uv = g.attributes.uv;
    const keep = new Map(), remap = new Int32Array(n), chosen = [];
    for (let i = 0; i < n; i++) {
      let key = Math.floor(P.getX(i) / cell) + ',' + Math.floor(P.getY(i) / cell) + ',' +
                Math.floor(P.getZ(i) / cell);
      if (uv) key += ',' + Math.floor(uv.getX(i) * 64) + ',' + Math.floor(uv.getY(i) * 64);
      let k = keep.get(key);
      if (k === undefined) { k = chosen.length; keep.set(key, k); chosen.push(i); }
      remap[i] = k;
    }
    const out = new T.BufferGeometry();
    for (const [name, attr] of Object.entries(g.attributes)) {
      const items = attr.itemSize, data = new attr.array.constructor(chosen.length * items);
      for (let k = 0; k < chosen.length; k++) {
        for (let c = 0; c < items; c++) data[k * items + c] = attr.array[chosen[k] * items + c];
      }
      out.setAttribute(name, new T.BufferAttribute(data, items, attr.normalized));
    }
    const index = g.index.array, faces = [];
    for (let f = 0; f < index.length; f += 3) {
      const a = remap[index[f]], b = remap[index[f + 1]], c = remap[index[f + 2]];
      if (a !== b && b !== c && a !== c) faces.push(a, b, c);
    }
    out.setIndex(faces);
    const proxy = new T.SkinnedMesh(out, mesh.material);
    proxy.frustumCulled = false;
    proxy.position.copy(mesh.position);
    proxy.quaternion.copy(mesh.quaternion);
    proxy.scale.copy(mesh.scale);
    proxy.bind(mesh.skeleton, mesh.bindMatrix);
    mesh.parent.add(proxy);
    return proxy;
  }

  function addLights(scene) {
    const hemi = new T.HemisphereLight(0xffffff, 0x444444, 1.6);
    const sun = new T.DirectionalLight(0xffffff, 1.8);
    sun.position.set(1.5, 3.0, 2.5);
    scene.add(hemi, sun);
  }

  async function main() {
    const settings = hashSettings();
    const layout = settings.layout || (DATA.keyframes ? 'both' : 'orbit');
    const glb = bytesOf('data-glb');
    const orbitGltf = await parseGlb(glb);
    const mesh = skinnedMeshOf(orbitGltf.scene);
    mesh.frustumCulled = false;

    // clips: the page's own (fitted poses, built-in motions), then the glb's
    const clips = [];
    for (const spec of DATA.clips) clips.push({ clip: clipOf(spec, orbitGltf.scene), world: spec.world });
    for (const clip of orbitGltf.animations) clips.push({ clip, world: false });
    if (!clips.length) throw new Error('no motion to show');

    // orbit view
    const orbitPane = document.getElementById('orbit');
    const antialias = settings.aa ? settings.aa !== '0' : !softwareWebgl();
    document.body.dataset.antialias = String(antialias);
    const orbitRenderer = new T.WebGLRenderer({ antialias, preserveDrawingBuffer: true });
    orbitRenderer.setClearColor(BACKGROUND);
    orbitPane.appendChild(orbitRenderer.domElement);
    const scene = new T.Scene();
    addLights(scene);
    const holder = new T.Group();
    holder.add(orbitGltf.scene);
    scene.add(holder);
    const skeleton = new T.SkeletonHelper(orbitGltf.scene);
    skeleton.visible = settings.skeleton === '1';
    scene.add(skeleton);
    const floor = new T.GridHelper(4, 16, 0x555a60, 0x383c42);
    floor.visible = settings.floor !== '0';
    scene.add(floor);
    const camera = new T.PerspectiveCamera(35, 1, 0.05, 100);
    const controls = new T.OrbitControls(camera, orbitRenderer.domElement);
    const height = DATA.height_m || 1.7;
    camera.position.set(0, height * 0.55, height * 2.2);
    controls.target.set(0, height * 0.5, 0);
    controls.update();

    // materials: shaded (the glb's), albedo (unlit texture), heat (unlit vertex colours)
    const shaded = mesh.material;
    const albedo = new T.MeshBasicMaterial({ map: shaded.map || null, color: shaded.map ? 0xffffff : 0xbbbbbb });
    let heat = null;
    if (DATA.heat) {
      const rgb = bytesOf('data-heat');
      const colors = new Float32Array(rgb.length);
      for (let i = 0; i < rgb.length; i++) colors[i] = rgb[i] / 255;
      if (colors.length !== 3 * mesh.geometry.attributes.position.count) {
        throw new Error('heat map and glb differ in vertex count');
      }
      mesh.geometry.setAttribute('color', new T.BufferAttribute(colors, 3));
      heat = new T.MeshBasicMaterial({ vertexColors: true });
    }

    // large meshes move as a coarse stand-in (#lod=VERTICES sets the size above which)
    const proxy = proxyOf(mesh, parseInt(settings.lod || '60000', 10), 25000);
    if (proxy) document.body.dataset.proxyVertices = String(proxy.geometry.attributes.position.count);
    let dragging = false;

    // overlay: the fitted avatar over the input frame, seen by the input camera
    let overlay = null;
    if (DATA.keyframes && layout !== 'orbit') {
      const overlayGltf = await parseGlb(glb);
      const oMesh = skinnedMeshOf(overlayGltf.scene);
      oMesh.frustumCulled = false;
      oMesh.material = new T.MeshNormalMaterial();
      const oScene = new T.Scene();
      oScene.add(overlayGltf.scene);
      const fitted = DATA.clips.find((c) => c.name === DATA.keyframes.clip);
      const oMixer = new T.AnimationMixer(overlayGltf.scene);
      const oAction = oMixer.clipAction(clipOf(fitted, overlayGltf.scene));
      oAction.play();
      const atlas = new Image();
      const atlasBlob = new Blob([bytesOf('data-atlas')], { type: 'image/jpeg' });
      atlas.src = URL.createObjectURL(atlasBlob);
      await atlas.decode();
      const oRenderer = new T.WebGLRenderer({ antialias: true, alpha: true, preserveDrawingBuffer: true });
      oRenderer.setClearColor(0x000000, 0);
      const frameCanvas = document.createElement('canvas');
      const pane = document.getElementById('overlay');
      pane.appendChild(frameCanvas);
      pane.appendChild(oRenderer.domElement);
      overlay = { mixer: oMixer, action: oAction, scene: oScene, renderer: oRenderer,
                  camera: inputCamera(DATA.camera), atlas, frameCanvas, pane, times: fitted.times };
    }
    document.getElementById('overlay').style.display = overlay ? '' : 'none';
    if (layout === 'overlay' && overlay) orbitPane.style.display = 'none';

    // state and controls
    const mixer = new T.AnimationMixer(orbitGltf.scene);
    const state = { index: 0, time: parseFloat(settings.t || '0'), paused: settings.paused === '1',
                    shading: settings.shading || 'shaded', heat: settings.heat === '1' && !!heat };
    let action = null;
    const select = document.getElementById('clip');
    clips.forEach((c, i) => {
      const o = document.createElement('option');
      o.value = String(i);
      o.textContent = c.clip.name;
      select.appendChild(o);
    });
    function useClip(i) {
      if (action) action.stop();
      state.index = i;
      const c = clips[i];
      action = mixer.clipAction(c.clip);
      action.play();
      holder.matrixAutoUpdate = false;
      if (c.world) {
        const m = uprightMatrix();
        const ctr = DATA.center;
        m.premultiply(new T.Matrix4().makeTranslation(-ctr[0], -ctr[1], -ctr[2]));
        holder.matrix.copy(m);
      } else {  // Y-up already: stand the rest pose's feet on the floor
        holder.matrix.makeTranslation(0, -DATA.floor_y, 0);
      }
      holder.updateMatrixWorld(true);
      select.value = String(i);
      slider.max = String(c.clip.duration);
    }
    const slider = document.getElementById('time');
    const wanted = clips.findIndex((c) => c.clip.name === settings.clip);
    if (settings.clip && wanted < 0) throw new Error('no motion named ' + settings.clip);
    select.addEventListener('change', () => { useClip(parseInt(select.value, 10)); state.time = 0; });
    slider.addEventListener('input', () => { state.time = parseFloat(slider.value); });
    const play = document.getElementById('play');
    play.addEventListener('click', () => { state.paused = !state.paused; });
    const shadingBox = document.getElementById('shading');
    shadingBox.value = state.shading;
    shadingBox.addEventListener('change', () => { state.shading = shadingBox.value; });
    const skeletonBox = document.getElementById('skeleton');
    skeletonBox.checked = skeleton.visible;
    skeletonBox.addEventListener('change', () => { skeleton.visible = skeletonBox.checked; });
    const heatBox = document.getElementById('heat');
    heatBox.checked = state.heat;
    heatBox.disabled = !heat;
    document.getElementById('heat-label').style.display = heat ? '' : 'none';
    heatBox.addEventListener('change', () => { state.heat = heatBox.checked; });
    useClip(wanted < 0 ? 0 : wanted);

    function fit(renderer, pane, aspect) {
      const w = Math.max(1, pane.clientWidth), h = Math.max(1, pane.clientHeight);
      let cw = w, ch = h;
      if (aspect) { if (w / h > aspect) cw = Math.round(h * aspect); else ch = Math.round(w / aspect); }
      const canvas = renderer.domElement;
      if (canvas.width !== cw || canvas.height !== ch) renderer.setSize(cw, ch, false);
      canvas.style.width = cw + 'px';
      canvas.style.height = ch + 'px';
      return [cw, ch];
    }

    function drawFrame(o, t) {
      const kf = DATA.keyframes;
      let k = 0;
      for (let i = 0; i < o.times.length; i++) if (Math.abs(o.times[i] - t) < Math.abs(o.times[k] - t)) k = i;
      const [cw, ch] = fit(o.renderer, o.pane, DATA.camera.width / DATA.camera.height);
      const fc = o.frameCanvas;
      if (fc.width !== cw || fc.height !== ch) { fc.width = cw; fc.height = ch; }
      fc.style.width = cw + 'px';
      fc.style.height = ch + 'px';
      const col = k % kf.cols, row = Math.floor(k / kf.cols);
      fc.getContext('2d').drawImage(o.atlas, col * kf.tile[0], row * kf.tile[1], kf.tile[0], kf.tile[1], 0, 0, cw, ch);
      document.getElementById('frame-label').textContent = 'input frame ' + DATA.keyframes.indices[k];
    }

    function render() {
      const c = clips[state.index];
      const d = c.clip.duration;
      const t = d > 0 ? ((state.time % d) + d) % d : 0;
      mixer.setTime(t);
      slider.value = String(t);
      document.body.dataset.played = state.time.toFixed(3);  // seconds on the clock, unwrapped
      play.textContent = state.paused ? 'play' : 'pause';
      mesh.material = state.heat ? heat : (state.shading === 'albedo' ? albedo : shaded);
      if (proxy) {
        const moving = !state.paused || dragging || settings.proxy === '1';
        proxy.material = mesh.material;
        proxy.visible = moving;
        mesh.visible = !moving;
      }
      const [w, h] = fit(orbitRenderer, orbitPane, null);
      camera.aspect = w / h;
      camera.updateProjectionMatrix();
      orbitRenderer.render(scene, camera);
      if (overlay) {
        const od = overlay.action.getClip().duration;
        const ot = c.world ? t : (od > 0 ? t % od : 0);
        overlay.mixer.setTime(ot);
        drawFrame(overlay, ot);
        overlay.renderer.render(overlay.scene, overlay.camera);
      }
    }

    let last = performance.now();
    // a still scene is drawn again only when something changed (the camera, a control, the
    // window's size)
    let dirty = true;
    const touch = () => { dirty = true; };
    controls.addEventListener('change', touch);
    controls.addEventListener('start', () => { dragging = true; });
    controls.addEventListener('end', () => { dragging = false; dirty = true; });
    window.addEventListener('resize', touch);
    for (const el of [select, slider, play, shadingBox, skeletonBox, heatBox]) {
      el.addEventListener('input', touch);
      el.addEventListener('change', touch);
      el.addEventListener('click', touch);
    }
    function loop(now) {
      if (!state.paused) state.time += (now - last) / 1000;
      last = now;
      controls.update();
      if (!state.paused || dirty) render();
      dirty = false;
      window.requestAnimationFrame(loop);
    }

    if (settings.bench) {
      const frames = parseInt(settings.bench, 10);
      render();
      const gl = orbitRenderer.getContext();
      const pixel = new Uint8Array(4);
      const start = performance.now();
      for (let i = 0; i < frames; i++) {
        state.time += 1 / 30;
        render();
        gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, pixel);  // waits for the frame
      }
      const fps = frames / ((performance.now() - start) / 1000);
      document.body.dataset.fps = fps.toFixed(2);
      document.body.dataset.vertices = String(mesh.geometry.attributes.position.count);
    }
    render();
    document.body.dataset.state = 'ready';
    document.body.dataset.clip = clips[state.index].clip.name;
    document.title = 'monoavatar view: ' + (DATA.title || 'avatar');
    status.textContent = (DATA.summary || []).join(' · ');
    window.requestAnimationFrame(loop);
  }

  main().catch((e) => fail(e && e.message ? e.message : String(e)));
})();
