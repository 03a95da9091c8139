// Runs the original TF.js CenterNet graph (pure-JS CPU backend) on a fixed 512x512 input and
// prints a strided subset of its heat-map and box outputs as JSON: the fixture
// tests/detector/fixtures/centernet_tfjs_reference.json of test_conversion_matches_stored_tfjs_output.
// Re-create (npm packages in a scratch folder outside the repository):
//   mkdir /tmp/tfjs && cd /tmp/tfjs && npm init -y && npm install @tensorflow/tfjs-core@4.22.0 \
//     @tensorflow/tfjs-converter@4.22.0 @tensorflow/tfjs-backend-cpu@4.22.0
//   NODE_PATH=/tmp/tfjs/node_modules node scripts/centernet_tfjs_reference.js \
//     .venv/pretrained/vladmandic-human-3.3.6 > tests/detector/fixtures/centernet_tfjs_reference.json
const fs = require('fs');
const path = require('path');
const tf = require('@tensorflow/tfjs-core');
require('@tensorflow/tfjs-backend-cpu');
const tfc = require('@tensorflow/tfjs-converter');

async function main() {
  const dir = process.argv[2];
  await tf.setBackend('cpu');
  const model = JSON.parse(fs.readFileSync(path.join(dir, 'centernet.json')));
  const specs = [].concat(...model.weightsManifest.map((g) => g.weights));
  const bufs = [].concat(...model.weightsManifest.map((g) => g.paths.map((p) => fs.readFileSync(path.join(dir, p)))));
  const data = Buffer.concat(bufs);
  const ab = data.buffer.slice(data.byteOffset, data.byteOffset + data.byteLength);
  const g = await tfc.loadGraphModel(tf.io.fromMemory({ modelTopology: model.modelTopology, weightSpecs: specs, weightData: ab }));
  const H = 512, W = 512;
  const px = new Float32Array(H * W * 3);
  for (let i = 0; i < H; i++) for (let j = 0; j < W; j++) for (let c = 0; c < 3; c++) {
    px[(i * W + j) * 3 + c] = (Math.floor(i / 16) * 37 + Math.floor(j / 16) * 91 + c * 53 + Math.floor((i * j) / 97)) % 256;
  }
  const x = tf.tensor4d(px, [1, H, W, 3]);
  const [kp, wh] = g.execute(x, ['tower_0/keypoints', 'tower_0/wh']);
  const step = 4;
  const kpa = await kp.array(), wha = await wh.array();
  const channels = [0, 2, 5, 7];
  const out = { input: 'v[i,j,c] = (floor(i/16)*37 + floor(j/16)*91 + c*53 + floor(i*j/97)) % 256, 512x512 RGB', step, channels, keypoints: [], wh: [] };
  for (let i = 0; i < kpa[0].length; i += step) {
    const rk = [], rw = [];
    for (let j = 0; j < kpa[0][i].length; j += step) {
      rk.push(channels.map((c) => Number(kpa[0][i][j][c].toPrecision(6))));
      rw.push(wha[0][i][j].map((v) => Number(v.toPrecision(6))));
    }
    out.keypoints.push(rk); out.wh.push(rw);
  }
  out.tfjs_version = tf.version_core;
  process.stdout.write(JSON.stringify(out));
}
main();
