// The GL renderer: owns the #gl canvas's context (WebGL 2 when the browser
// gives one, WebGL 1 otherwise), the puppets' GPU buffers and textures,
// drawing the textured meshes bottom to top, reading pixels back for tests,
// and rebuilding everything after a lost context is restored.

// GLSL ES 1.00: WebGL 1 and WebGL 2 both compile it, so both draw alike.
const VERTEX_SHADER = `
attribute vec2 a_pos;
attribute vec2 a_uv;
uniform vec2 u_stage;
varying vec2 v_uv;
void main() {
  v_uv = a_uv;
  // Stage and clip space are both y-up, so no flip here.
  gl_Position = vec4(a_pos / u_stage * 2.0 - 1.0, 0.0, 1.0);
}`;

const FRAGMENT_SHADER = `
precision mediump float;
uniform sampler2D u_tex;
varying vec2 v_uv;
void main() { gl_FragColor = texture2D(u_tex, v_uv); }`;

// The stage's colour; an mp4 export is composited over the same
// (crates/export/src/video.rs STAGE_COLOUR).
const BACKGROUND = [0.96, 0.95, 0.92, 1];
// A transparent page (OBS's browser source keys on alpha): clear to nothing.
// The pictures are premultiplied, and so is what the canvas hands on.
const CLEAR = [0, 0, 0, 0];
const MAX_USHORT_VERTICES = 65535;

// WebGL 2 if the browser has it, else WebGL 1; null if neither.
// (Once a canvas has a context, asking for the other kind gives null, so a
// restored canvas gets the kind it had.)
function createContext(canvas, transparent) {
  const options = { alpha: transparent, premultipliedAlpha: true, antialias: true };
  const gl2 = canvas.getContext('webgl2', options);
  if (gl2) return { gl: gl2, version: 2 };
  const gl1 = canvas.getContext('webgl', options);
  return gl1 ? { gl: gl1, version: 1 } : null;
}

export class MeshRenderer {
  /**
   * hooks: onError(message), onTextureLoaded() (the picture changed: draw
   * again), onRestored() (after a lost context was rebuilt).
   * transparent: the stage's background is transparent, not paper.
   */
  constructor(canvas, hooks, { transparent = false } = {}) {
    this.canvas = canvas;
    this.hooks = hooks;
    this.transparent = transparent;
    this.gl = null;
    this.webglVersion = 0;      // 2 or 1 once init() succeeded
    this.program = null;
    this.locations = null;
    this.placeholder = null;    // shown until a picture has loaded
    this.textures = new Map();  // url -> WebGLTexture, shared by puppets with one picture
    this.stageSize = null;      // {width, height} in stage units
    this.puppets = [];          // the puppet states being drawn, bottom to top
    this.meshes = [];           // their GPU buffers, in the same order

    canvas.addEventListener('webglcontextlost', (e) => {
      e.preventDefault(); // tells the browser we will rebuild, so it restores the context
      this.hooks.onError('graphics context lost');
    });
    canvas.addEventListener('webglcontextrestored', () => {
      this.init();
      if (this.puppets.length) this.setStage(this.stageSize, this.puppets);
      this.hooks.onRestored();
    });
  }

  /** Creates the context and program; throws when there is no WebGL. */
  init() {
    const context = createContext(this.canvas, this.transparent);
    if (!context) throw new Error('WebGL is not available');
    const { gl } = context;
    this.gl = gl;
    this.webglVersion = context.version;
    const shader = (type, src) => {
      const s = gl.createShader(type);
      gl.shaderSource(s, src);
      gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
      return s;
    };
    const program = gl.createProgram();
    gl.attachShader(program, shader(gl.VERTEX_SHADER, VERTEX_SHADER));
    gl.attachShader(program, shader(gl.FRAGMENT_SHADER, FRAGMENT_SHADER));
    gl.linkProgram(program);
    if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
    this.program = program;
    this.locations = {
      pos: gl.getAttribLocation(program, 'a_pos'),
      uv: gl.getAttribLocation(program, 'a_uv'),
      stage: gl.getUniformLocation(program, 'u_stage'),
    };
    gl.enableVertexAttribArray(this.locations.pos);
    gl.enableVertexAttribArray(this.locations.uv);
    // Pictures have soft alpha edges: upload premultiplied and blend accordingly.
    gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, true);
    // uv has v down from the top of the picture, and WebGL stores the first image
    // row at t = 0: so no flip. (Flipping would need v' = 1 - v.)
    gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, false);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
    this.placeholder = this.makeTexture(new Uint8Array([200, 200, 200, 255]));
    this.textures.clear();
    this.meshes = []; // buffers of a lost context are gone with it
  }

  makeTexture(pixel) {
    const gl = this.gl;
    const tex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, tex);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, 1, 1, 0, gl.RGBA, gl.UNSIGNED_BYTE, pixel);
    // WebGL 1 cannot mipmap or repeat non-power-of-two pictures (and WebGL 2
    // draws them the same way with these settings).
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
    return tex;
  }

  /** Starts loading a picture once per url; settles when it is loaded or failed. */
  loadTexture(url) {
    if (this.textures.has(url)) return Promise.resolve();
    const gl = this.gl;
    const tex = this.makeTexture(new Uint8Array([0, 0, 0, 0]));
    this.textures.set(url, tex);
    const img = new Image();
    img.src = url;
    return img.decode().then(
      () => {
        if (this.textures.get(url) !== tex) return; // context was rebuilt meanwhile
        gl.bindTexture(gl.TEXTURE_2D, tex);
        gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, img);
        this.hooks.onTextureLoaded();
      },
      () => this.hooks.onError(`cannot load texture ${url}`),
    );
  }

  /**
   * The stage to draw: its size and its puppets (see app.js's puppet state:
   * id, n, positions, dirty, texture, src.uv, src.triangles). Replaces the
   * GPU buffers; the promise settles when every picture has loaded or failed.
   */
  setStage(stageSize, puppets) {
    const gl = this.gl;
    for (const m of this.meshes) {
      gl.deleteBuffer(m.posBuf);
      gl.deleteBuffer(m.uvBuf);
      gl.deleteBuffer(m.idxBuf);
    }
    // Pictures no puppet shows any more go: a removed puppet's id, and so
    // its picture's address, never comes back.
    const shown = new Set(puppets.map((p) => p.texture));
    for (const [url, tex] of this.textures) {
      if (shown.has(url)) continue;
      gl.deleteTexture(tex);
      this.textures.delete(url);
    }
    this.stageSize = stageSize;
    this.puppets = puppets;
    this.meshes = puppets.map((p) => {
      const big = p.n > MAX_USHORT_VERTICES;
      if (big && this.webglVersion < 2 && !gl.getExtension('OES_element_index_uint')) {
        this.hooks.onError(`puppet ${p.id} has ${p.n} vertices; this GPU draws at most ${MAX_USHORT_VERTICES}`);
      }
      const posBuf = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, posBuf);
      gl.bufferData(gl.ARRAY_BUFFER, p.positions, gl.DYNAMIC_DRAW);
      p.dirty = false;
      const uvBuf = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, uvBuf);
      gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(p.src.uv), gl.STATIC_DRAW);
      const idxBuf = gl.createBuffer();
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, idxBuf);
      const indices = big ? new Uint32Array(p.src.triangles) : new Uint16Array(p.src.triangles);
      gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, indices, gl.STATIC_DRAW);
      return {
        puppet: p, posBuf, uvBuf, idxBuf,
        idxType: big ? gl.UNSIGNED_INT : gl.UNSIGNED_SHORT,
        count: p.src.triangles.length,
      };
    });
    return Promise.all(puppets.map((p) => this.loadTexture(p.texture)));
  }

  draw() {
    const gl = this.gl;
    gl.viewport(0, 0, this.canvas.width, this.canvas.height);
    gl.clearColor(...(this.transparent ? CLEAR : BACKGROUND));
    gl.clear(gl.COLOR_BUFFER_BIT);
    if (!this.stageSize) return;
    const loc = this.locations;
    gl.useProgram(this.program);
    gl.uniform2f(loc.stage, this.stageSize.width, this.stageSize.height);
    for (const m of this.meshes) {
      const p = m.puppet;
      gl.bindBuffer(gl.ARRAY_BUFFER, m.posBuf);
      if (p.dirty) {
        // Only the newest frame is uploaded, straight from the message's buffer.
        gl.bufferSubData(gl.ARRAY_BUFFER, 0, p.positions);
        p.dirty = false;
      }
      gl.vertexAttribPointer(loc.pos, 2, gl.FLOAT, false, 0, 0);
      gl.bindBuffer(gl.ARRAY_BUFFER, m.uvBuf);
      gl.vertexAttribPointer(loc.uv, 2, gl.FLOAT, false, 0, 0);
      gl.bindTexture(gl.TEXTURE_2D, this.textures.get(p.texture) ?? this.placeholder);
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, m.idxBuf);
      if (p.drawOrder) {
        // A new depth: the triangles, back to front (see depthOrder).
        const typed = m.idxType === gl.UNSIGNED_INT ? Uint32Array : Uint16Array;
        gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, new typed(p.drawOrder), gl.DYNAMIC_DRAW);
        p.drawOrder = null;
      }
      gl.drawElements(gl.TRIANGLES, m.count, m.idxType, 0);
    }
  }

  /**
   * Draws now and reads the result back in the same task, before the browser
   * presents (and may clear) the drawing buffer. For tests: RGBA bytes,
   * bottom row first.
   */
  snapshot() {
    this.draw();
    const gl = this.gl;
    const px = new Uint8Array(this.canvas.width * this.canvas.height * 4);
    gl.readPixels(0, 0, this.canvas.width, this.canvas.height, gl.RGBA, gl.UNSIGNED_BYTE, px);
    return px;
  }
}
