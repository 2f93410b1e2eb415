// XXH64 (seed 0) of a byte string, as the low 32 bits: zstd's frame content checksum.
// 64-bit lanes are kept as (hi, lo) pairs of u32, multiplied in 16-bit limbs (no BigInt in the
// hot loop).

const P1 = [0x9e3779b1, 0x85ebca87] as const;
const P2 = [0xc2b2ae3d, 0x27d4eb4f] as const;
const P3 = [0x165667b1, 0x9e3779f9] as const;
const P4 = [0x85ebca77, 0xc2b2ae63] as const;
const P5 = [0x27d4eb2f, 0x165667c5] as const;

// The result of the last operation (hi, lo): avoids allocating a pair per step.
let rh = 0;
let rl = 0;

function mul(ah: number, al: number, bh: number, bl: number): void {
  const a48 = ah >>> 16, a32 = ah & 0xffff, a16 = al >>> 16, a00 = al & 0xffff;
  const b48 = bh >>> 16, b32 = bh & 0xffff, b16 = bl >>> 16, b00 = bl & 0xffff;
  let c00 = a00 * b00;
  let c16 = c00 >>> 16;
  c00 &= 0xffff;
  c16 += a16 * b00;
  let c32 = Math.floor(c16 / 0x10000);
  c16 &= 0xffff;
  c16 += a00 * b16;
  c32 += Math.floor(c16 / 0x10000);
  c16 &= 0xffff;
  c32 += a32 * b00;
  let c48 = Math.floor(c32 / 0x10000);
  c32 &= 0xffff;
  c32 += a16 * b16;
  c48 += Math.floor(c32 / 0x10000);
  c32 &= 0xffff;
  c32 += a00 * b32;
  c48 += Math.floor(c32 / 0x10000);
  c32 &= 0xffff;
  c48 += a48 * b00 + a32 * b16 + a16 * b32 + a00 * b48;
  rh = (((c48 % 0x10000) << 16) | c32) >>> 0;
  rl = ((c16 << 16) | c00) >>> 0;
}

function add(ah: number, al: number, bh: number, bl: number): void {
  const lo = al + bl;
  rl = lo >>> 0;
  rh = (ah + bh + (lo > 0xffffffff ? 1 : 0)) >>> 0;
}

function rotl(h: number, l: number, r: number): void {
  if (r >= 32) {
    const t = h;
    h = l;
    l = t;
    r -= 32;
  }
  if (r === 0) {
    rh = h;
    rl = l;
    return;
  }
  rh = ((h << r) | (l >>> (32 - r))) >>> 0;
  rl = ((l << r) | (h >>> (32 - r))) >>> 0;
}

/** round(acc, input) = rotl(acc + input * P2, 31) * P1 */
function round(ah: number, al: number, ih: number, il: number): void {
  mul(ih, il, P2[0], P2[1]);
  add(ah, al, rh, rl);
  rotl(rh, rl, 31);
  mul(rh, rl, P1[0], P1[1]);
}

/** acc = (acc ^ round(0, v)) * P1 + P4 */
function merge(ah: number, al: number, vh: number, vl: number): void {
  round(0, 0, vh, vl);
  const xh = (ah ^ rh) >>> 0, xl = (al ^ rl) >>> 0;
  mul(xh, xl, P1[0], P1[1]);
  add(rh, rl, P4[0], P4[1]);
}

/** The low 32 bits of XXH64(data, seed 0). */
export function xxh64Low32(data: Uint8Array): number {
  const n = data.length;
  const u32 = (at: number): number =>
    (data[at]! | (data[at + 1]! << 8) | (data[at + 2]! << 16) | (data[at + 3]! << 24)) >>> 0;
  let p = 0;
  let hh: number, hl: number;
  if (n >= 32) {
    add(P1[0], P1[1], P2[0], P2[1]);
    let v1h = rh, v1l = rl;
    let v2h: number = P2[0], v2l: number = P2[1];
    let v3h = 0, v3l = 0;
    add(0, 0, ~P1[0] >>> 0, ~P1[1] >>> 0); // -P1 = ~P1 + 1
    add(rh, rl, 0, 1);
    let v4h = rh, v4l = rl;
    for (const limit = n - 32; p <= limit; p += 32) {
      round(v1h, v1l, u32(p + 4), u32(p));
      v1h = rh; v1l = rl;
      round(v2h, v2l, u32(p + 12), u32(p + 8));
      v2h = rh; v2l = rl;
      round(v3h, v3l, u32(p + 20), u32(p + 16));
      v3h = rh; v3l = rl;
      round(v4h, v4l, u32(p + 28), u32(p + 24));
      v4h = rh; v4l = rl;
    }
    rotl(v1h, v1l, 1);
    let sh = rh, sl = rl;
    rotl(v2h, v2l, 7);
    add(sh, sl, rh, rl);
    sh = rh; sl = rl;
    rotl(v3h, v3l, 12);
    add(sh, sl, rh, rl);
    sh = rh; sl = rl;
    rotl(v4h, v4l, 18);
    add(sh, sl, rh, rl);
    merge(rh, rl, v1h, v1l);
    merge(rh, rl, v2h, v2l);
    merge(rh, rl, v3h, v3l);
    merge(rh, rl, v4h, v4l);
    hh = rh; hl = rl;
  } else {
    hh = P5[0]; hl = P5[1];
  }
  // h += len (a length below 2^53)
  add(hh, hl, Math.floor(n / 0x100000000) >>> 0, n >>> 0);
  hh = rh; hl = rl;
  for (; p + 8 <= n; p += 8) {
    round(0, 0, u32(p + 4), u32(p));
    const xh = (hh ^ rh) >>> 0, xl = (hl ^ rl) >>> 0;
    rotl(xh, xl, 27);
    mul(rh, rl, P1[0], P1[1]);
    add(rh, rl, P4[0], P4[1]);
    hh = rh; hl = rl;
  }
  if (p + 4 <= n) {
    mul(0, u32(p), P1[0], P1[1]);
    const xh = (hh ^ rh) >>> 0, xl = (hl ^ rl) >>> 0;
    rotl(xh, xl, 23);
    mul(rh, rl, P2[0], P2[1]);
    add(rh, rl, P3[0], P3[1]);
    hh = rh; hl = rl;
    p += 4;
  }
  for (; p < n; p++) {
    mul(0, data[p]!, P5[0], P5[1]);
    const xh = (hh ^ rh) >>> 0, xl = (hl ^ rl) >>> 0;
    rotl(xh, xl, 11);
    mul(rh, rl, P1[0], P1[1]);
    hh = rh; hl = rl;
  }
  // avalanche: h ^= h >> 33; h *= P2; h ^= h >> 29; h *= P3; h ^= h >> 32
  hl = (hl ^ (hh >>> 1)) >>> 0;
  mul(hh, hl, P2[0], P2[1]);
  hh = rh; hl = rl;
  const sh = hh >>> 29, sl = ((hh << 3) | (hl >>> 29)) >>> 0;
  mul((hh ^ sh) >>> 0, (hl ^ sl) >>> 0, P3[0], P3[1]);
  return (rl ^ rh) >>> 0;
}
