// Colours the 3D view and the resectogram share (no DOM, no vtk.js: testable in Node).

import type { VesselSystem } from "./api";

/** RGBA per margin class code (outside, safe, warning, violation), as the Slicer module. */
export const MARGIN_CLASS_RGBA: readonly [number, number, number, number][] = [
  [0.86, 0.86, 0.86, 0.35],
  [0.62, 0.62, 0.62, 1.0],
  [1.0, 0.85, 0.0, 1.0],
  [0.9, 0.05, 0.05, 1.0],
];

/** The colour a cut vessel is marked in: portal blue, hepatic purple. */
export const CUT_VESSEL_RGB: Record<VesselSystem, [number, number, number]> = {
  VESSEL_SYSTEM_PORTAL: [0.1, 0.35, 1.0],
  VESSEL_SYSTEM_HEPATIC: [0.6, 0.15, 0.8],
};
