// The parts of three.js the replay viewer uses (uvms_env/replay_assets/viewer.html), bundled
// into one classic script that defines the global THREE, so a replay page needs no module
// loader, no server and no network. Rebuild (three and esbuild pinned):
//   npm install three@0.187.0 esbuild@0.28.2
//   npx esbuild three-entry.js --bundle --minify --format=iife --global-name=THREE \
//     --legal-comments=inline --outfile=three-0.187.0.min.js \
//     "--banner:js=/*! three.js 0.187.0 | MIT License | Copyright (c) 2010-2026 three.js
//     authors | subset bundled by esbuild 0.28.2 from uvms_env/replay_assets/three-entry.js */"
// (the banner on one line; the full licence text is LICENSE.three beside it).
export {
  AmbientLight,
  AxesHelper,
  BufferAttribute,
  BufferGeometry,
  CapsuleGeometry,
  Color,
  CylinderGeometry,
  DirectionalLight,
  GridHelper,
  Group,
  HemisphereLight,
  Line,
  LineBasicMaterial,
  Mesh,
  MeshBasicMaterial,
  MeshLambertMaterial,
  OctahedronGeometry,
  PerspectiveCamera,
  Quaternion,
  Scene,
  SphereGeometry,
  Vector3,
  WebGLRenderer,
} from "three";
export { OrbitControls } from "three/addons/controls/OrbitControls.js";
