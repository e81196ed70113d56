// Entry of the vendored three.js bundle: the parts of the npm `three` package the viewer uses,
// exposed as one global (window.THREE) so that the page needs no modules and opens from file://.
import * as THREE_CORE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
window.THREE = Object.assign({}, THREE_CORE, { GLTFLoader, OrbitControls });
