// tinbuild verify: an independent check of a TIN (libterrain/delaunay/mesh_verifier.h), and of its vertices
// against the survey it was built from.
#pragma once

#include <cstdint>
#include <string>

#include "app/jobs/job_options.h"
#include "libterrain/core/diagnostics.h"
#include "libterrain/delaunay/mesh_verifier.h"

namespace tinbuild {

// `tinbuild verify`: checks a streaming mesh file independently (libterrain/delaunay/mesh_verifier.h) and,
// when options.inputs is not empty, that its vertices are exactly the distinct (x, y) of those inputs after
// options.finalizer.filter.  Memory is bounded by the mesh's and the survey's stream width.
struct VerifyReport {
  std::string mesh;
  MeshCheckReport check;
  bool pointsChecked = false;
  bool pointsCountable = true;  // false: the inputs were too incoherent for the memory budget
  std::uint64_t inputPoints = 0, inputDistinct = 0, inputDuplicates = 0;
  bool pointsMatch = false;
  // --breaklines/--water with --points: every constraint piece a TIN edge, every constraint vertex a TIN
  // vertex at its height.
  bool constraintsChecked = false;
  std::uint64_t pieces = 0, piecesMissing = 0, constraintVerticesMissing = 0, heightsDiffering = 0;
  std::string firstMissingPiece;
  // --water: every lake (a water body of joined polygons) flat at its level.
  bool waterChecked = false;
  std::uint64_t lakes = 0, lakesNotFlat = 0;
  double worstLakeSpread = 0;
  std::string firstLakeNotFlat;
  // Water at or below the ground: the TIN's vertices within the bank band of a shore (bank_check.h).  Below
  // a derived level: a problem; below a level given with its polygon: said (the user's level).
  bool banksChecked = false;
  std::uint64_t bankVertices = 0, bankBelowDerived = 0, bankBelowGiven = 0;
  std::string worstBank, worstBankDerived;
  double seconds = 0;
  bool constraintsOk() const {
    return piecesMissing == 0 && constraintVerticesMissing == 0 && heightsDiffering == 0 && lakesNotFlat == 0;
  }
  bool ok() const {
    return check.ok() && (!pointsChecked || pointsMatch) && (!constraintsChecked || constraintsOk()) &&
           bankBelowDerived == 0;
  }
};
VerifyReport runVerify(const std::string& mesh, const PipelineOptions& options, Diagnostics& diag);
std::string formatVerifyText(const VerifyReport& report);
std::string formatVerifyJson(const VerifyReport& report);

}  // namespace tinbuild
