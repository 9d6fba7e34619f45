// libterrain: the streaming core, pure C++20 with no GDAL, PROJ or file formats.
//
// The data flow (docs/design.md, "The pipeline"):
//   PointStream (pulled in batches, several passes) -> finalizer -> PointSink (points and finalization
//   tags) -> ParallelDelaunay (StreamingDelaunay per region, certified seams) -> MeshSink (vertices,
//   triangles, vertex finalization) -> MeshTee ->
//   outputs, among them the DemRasterizer.
//
// The folders (docs/design.md, "The tree"):
//   core/       errors (Error, DataError, UsageError, CancelledError), Diagnostics (warn once per kind,
//               count every time), JSON and report text, the GDAL-style progress convention, WorkCrew
//               (decode threads), TempFile (spill and spool files, unlinked at once), points and boxes.
//   finalizer/  the spatial finalizer: the 2^k grid (CellMap, bit-exact membership), its quadtree regions
//               in Morton order (one rule for the plan, its parts and the parallel triangulator),
//               PointStream and PointSink, point filters, chunking with a memory budget and spill, BRIO,
//               sprinkles, the read order of pass 3, survey statistics.
//   delaunay/   exact predicates (floating-point filter, exact fallback, symbolic perturbation), the
//               streaming Delaunay triangulator (certification against finalized space), the parallel
//               one (quadtree regions on threads, certified seams, the same bytes for any thread
//               count), the verifier.
//   mesh/       MeshSink / TriangleSink and the MeshTee that fans a mesh out to many outputs, on a writer
//               thread when asked, with checkpoint agents for "is this area complete?".
//   raster/     the DEM rasterizer: TIN interpolation at pixel centres, tiles released when complete.
//   contour/    the streaming contour tracer: isolines cut from the mesh as it streams, chained into lines.
//   hydro/      breaklines and hydro-flattening: water levels from bank points and river stations, the
//               conforming split (constraint pieces made Delaunay edges), the water and breakline stages,
//               the constraint vertices as a stream, verify's edge check.
//   hydrology/  terrain hydrology on DEM tiles, each pass keeping only its tiles' perimeters: the fill
//               (spill graph), D8 flow directions with flats, upstream area, stream links and Strahler
//               orders, HAND, the depth for a stage and the catchments.
//   synthetic/  realistic synthetic surveys (terrain, classes, returns, flight strips) for the demo,
//               tests and benchmarks.
// Nothing here includes formats/ or app/.
#pragma once

#include "libterrain/contour/contour_tracer.h"
#include "libterrain/core/error.h"
#include "libterrain/delaunay/parallel_delaunay.h"
#include "libterrain/delaunay/streaming_delaunay.h"
#include "libterrain/finalizer/finalizer.h"
#include "libterrain/mesh/mesh_tee.h"
#include "libterrain/raster/dem_rasterizer.h"
