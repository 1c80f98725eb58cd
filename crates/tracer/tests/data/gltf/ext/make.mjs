import { Document, NodeIO } from '@gltf-transform/core';
import { KHRDracoMeshCompression, ALL_EXTENSIONS } from '@gltf-transform/extensions';
import { draco } from '@gltf-transform/functions';
import draco3d from 'draco3dgltf';

// A 9x9 grid, gently curved, with normals and texture coordinates.
const N = 9;
const pos = [], nor = [], uv = [], idx = [];
for (let j = 0; j < N; j++) for (let i = 0; i < N; i++) {
  const x = i / (N - 1), y = j / (N - 1);
  const z = 0.25 * (x - 0.5) * (x - 0.5) - 0.125 * y * y;
  pos.push(x * 2 - 1, y * 2 - 1, z);
  // normal of z = f(x,y) with f over the [-1,1] domain: (-dz/dX, -dz/dY, 1)
  const dzdx = 0.25 * 2 * (x - 0.5) * 0.5, dzdy = -0.125 * 2 * y * 0.5;
  const l = Math.hypot(dzdx, dzdy, 1);
  nor.push(-dzdx / l, -dzdy / l, 1 / l);
  uv.push(x, 1 - y);
}
for (let j = 0; j < N - 1; j++) for (let i = 0; i < N - 1; i++) {
  const a = j * N + i, b = a + 1, c = a + N, d = c + 1;
  idx.push(a, b, d, a, d, c);
}
const doc = new Document();
const buf = doc.createBuffer();
const prim = doc.createPrimitive()
  .setAttribute('POSITION', doc.createAccessor().setType('VEC3').setArray(new Float32Array(pos)).setBuffer(buf))
  .setAttribute('NORMAL', doc.createAccessor().setType('VEC3').setArray(new Float32Array(nor)).setBuffer(buf))
  .setAttribute('TEXCOORD_0', doc.createAccessor().setType('VEC2').setArray(new Float32Array(uv)).setBuffer(buf))
  .setIndices(doc.createAccessor().setType('SCALAR').setArray(new Uint16Array(idx)).setBuffer(buf));
const mesh = doc.createMesh('grid').addPrimitive(prim);
const node = doc.createNode('grid').setMesh(mesh);
doc.createScene().addChild(node);
const io = new NodeIO().registerExtensions(ALL_EXTENSIONS).registerDependencies({
  'draco3d.encoder': await draco3d.createEncoderModule(),
  'draco3d.decoder': await draco3d.createDecoderModule(),
});
await io.write('out/source.glb', doc);
const d1 = await io.read('out/source.glb');
await d1.transform(draco({ method: 'edgebreaker' }));
await io.write('out/draco_edgebreaker.glb', d1);
const d2 = await io.read('out/source.glb');
await d2.transform(draco({ method: 'sequential' }));
await io.write('out/draco_sequential.glb', d2);
