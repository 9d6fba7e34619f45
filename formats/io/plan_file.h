// The plan of a job split into parts (`tinbuild plan`), and the record a finished part leaves (its
// "done" file).  Both are JSON; the merge and every part read the plan, the merge reads the done files.
//
// A plan pins everything a part must agree on with the others: the inputs (path, size and modification
// time: a changed input makes the plan stale), the build's own arguments, the finalizer's grid (bit for
// bit: doubles are stored as hexadecimal floating-point strings beside a readable value), the region
// level and each part's Morton range of regions.  Its id is a hash of all that; every file a part writes
// carries the id, so the merge can tell a part of this plan from a leftover of another.
//
// Files beside PLAN.json: the state directory PLAN.parts/ holds part-NNNN.seam (seam_file.h),
// part-NNNN.dem (DEM pieces, dem_pieces.h) and part-NNNN.json (the done file, written last).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "formats/crs/crs.h"
#include "libterrain/core/point.h"
#include "libterrain/finalizer/grid.h"
#include "libterrain/hydro/bank_check.h"

namespace tinbuild {

struct PlanInput {
  std::string path;
  std::uint64_t bytes = 0;
  std::int64_t mtimeNs = 0;
};

struct PlanPart {
  std::uint64_t first = 0, end = 0;  // regions [first, end) in Morton order at Plan::regionLevel
  std::uint64_t points = 0;          // counted by the plan
};

// A run of records of an input and the box of its points after the filters (empty: none kept).  A part
// reads only the segments whose box meets its window.
struct PlanSegment {
  std::uint32_t input = 0;
  std::uint64_t first = 0, count = 0;
  double minX = 0, minY = 0, maxX = 0, maxY = 0;
  bool empty() const { return !(minX <= maxX); }
};

struct Plan {
  std::string id;                      // set by writePlan / readPlan
  std::string command;                 // the build command the plan stands for (recorded in outputs)
  std::vector<std::string> buildArgs;  // its arguments after "build"
  std::vector<PlanInput> inputs;
  GridSpec grid;
  Bounds3 bounds;
  std::uint64_t points = 0;
  int regionLevel = 1;
  std::vector<PlanPart> parts;
  // The parts' counts are exact (the points were read), so each part must triangulate exactly as many;
  // false when they were estimated from a COPC hierarchy (no point read).
  bool exactCounts = true;
  std::vector<PlanSegment> segments;  // of the inputs cut into several (LAS/LAZ read in their own CRS)
  // --breaklines/--water: the fingerprint of the constraints the plan prepared for its parts
  // (constraintsFile()); "" = none.
  std::string constraints;
  std::string path;  // where it was read from / written to

  // PLAN.parts (PLAN without its .json).
  std::string stateDir() const;
  std::string partFile(int part, const std::string& extension) const;  // stateDir/part-NNNN.extension
  std::string constraintsFile() const;                                 // stateDir/constraints.bin
};

// The input as it is now (size, modification time).  Throws DataError when it cannot be asked.
PlanInput describeInput(const std::string& path);
// Throws DataError naming the first input that changed since the plan (the plan is stale).
void checkPlanInputs(const Plan& plan);

// Computes the id and writes the plan atomically.
void writePlan(Plan& plan, const std::string& path);
// Throws DataError naming the file when it is not a plan or is damaged.
Plan readPlan(const std::string& path);

// What a finished part did (PLAN.parts/part-NNNN.json).
// A file a part leaves for the merge, as the part saw it when it finished: its size and a fingerprint of its
// bytes (all of them, or for a large part mesh its first and last MiB: `whole` false).  The merge checks
// every one before it writes anything.
struct PartFile {
  std::string role;  // "seam", "dem-pieces", "mesh"
  std::string path;
  std::uint64_t size = 0;
  std::string fingerprint;
  bool whole = true;
};

// The fingerprint of a file: 16 hex digits of a 64-bit hash of its bytes (whole), or of its size, first and
// last MiB (!whole).  DataError naming the file when it cannot be read.
std::string fileFingerprint(const std::string& path, bool whole);

struct PartDone {
  std::string planId;
  int part = 0;
  std::uint64_t points = 0;           // triangulated here
  std::uint64_t otherPartPoints = 0;  // read and left to other parts
  std::uint64_t triangles = 0;        // certified, written here
  std::uint64_t vertices = 0;         // written here (seam vertices among them)
  std::uint64_t seamVertices = 0;
  std::uint64_t seamBytes = 0, pieceBytes = 0;
  std::uint64_t demPieces = 0;
  std::string mesh;                   // the part's mesh file ("" = none)
  std::vector<std::string> demTiles;  // tiles written whole
  double seconds = 0;
  std::uint64_t peakRssBytes = 0;
  // The run's working CRS as the part's survey chose it, every field exactly, and the unit of z in metres:
  // the merge labels its outputs with it and converts the DEM's lengths by it, without opening an input.
  CrsInfo crs;
  double zUnitToMetre = 1;
  std::vector<PartFile> files;  // the seam file, the DEM pieces, the part's mesh
  // Hydro-flattening's product check of the DEM pixels this part computed (bank_check.h): absent when
  // not run.
  bool bankChecked = false;
  BankCheckFigures bank;
};

// Checks that every file a part recorded is there, of its size and fingerprint: DataError naming the part,
// the file and what is wrong (missing, short, altered), and how to redo it.  The state files are looked for
// in `plan`'s state directory (an MPI rank wrote its own elsewhere and sent them), the mesh where it was
// written.
void checkPartFiles(const PartDone& done, const Plan& plan);
void writePartDone(const PartDone& done, const std::string& path);
PartDone readPartDone(const std::string& path);

// The manifest of a TIN written in parts: the parts' mesh files and the seam's, which together hold every
// triangle once (`tinbuild verify` and `tinbuild info` read it as one TIN).
struct MeshManifest {
  std::string planId;
  std::vector<std::string> parts;  // paths as written (relative to the manifest's directory when relative)
  std::string seam;                // the top seam step's triangles
  std::vector<std::string> seamBlocks;  // an MPI run's: each rank's block steps' triangles (may be none)
  std::uint64_t triangles = 0, vertices = 0;  // distinct vertices of the whole TIN
  std::string crsWkt;                         // the TIN's CRS ("" = none)
  Bounds3 bounds;                             // of the survey
};
void writeMeshManifest(const MeshManifest& m, const std::string& path);
MeshManifest readMeshManifest(const std::string& path);
// Does the file start like a mesh manifest (a JSON object with "tinbuild_mesh_parts")?
bool isMeshManifest(const std::string& path);

// tin.smb -> tin.part-0003.smb, tin.seam.smb, tin.parts.json.
std::string partMeshPath(const std::string& mesh, int part);
std::string seamMeshPath(const std::string& mesh);
// tin.smb -> tin.seam-0003.smb: the triangles rank 3's seam blocks wrote (an MPI run).
std::string seamBlockMeshPath(const std::string& mesh, int rank);
std::string meshManifestPath(const std::string& mesh);

}  // namespace tinbuild
