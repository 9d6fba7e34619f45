#include "app/jobs/verify_job.h"

#include "app/jobs/constraints.h"
#include "app/jobs/survey.h"
#include "app/jobs/tin_parts.h"
#include "formats/io/plan_file.h"
#include "formats/mesh/streaming_mesh.h"
#include "libterrain/core/error.h"
#include "libterrain/core/json_writer.h"
#include "libterrain/core/report_text.h"
#include "libterrain/finalizer/survey_stats.h"
#include "libterrain/hydro/bank_check.h"
#include "libterrain/hydro/hydro_stage.h"

namespace tinbuild {

VerifyReport runVerify(const std::string& mesh, const PipelineOptions& o, Diagnostics& diag) {
  const auto t0 = JobClock::now();
  VerifyReport r;
  r.mesh = mesh;
  // Every check reads the TIN again, one streaming mesh or a TIN written in parts (tinbuild merge).
  auto readTin = [&mesh](MeshSink& sink) {
    if (isMeshManifest(mesh))
      readMeshParts(mesh, sink);
    else
      readStreamingMesh(mesh, sink);
  };
  MeshVerifier verifier;
  readTin(verifier);
  r.check = verifier.report();
  if (o.constraints.any() && o.inputs.empty())
    throw UsageError("verify --breaklines/--water: give the inputs the mesh was built from (--points INPUT...): "
                     "the constraints are placed from the survey's extent, spacing and shores");
  if (!o.inputs.empty()) {
    // The same inputs, CRS handling (--t_srs, UTM for geographic input) and filters as `build`.
    Survey in = openSurvey(o, diag);
    // The same constraints too: their stages and vertices are part of what the mesh must hold.
    FinalizerOptions fo = o.finalizer;
    const PreparedConstraints constraints = prepareConstraints(o, in, diag);
    applyConstraints(constraints, fo, in);
    if (!constraints.empty()) {
      ConstraintEdgeCheck edges(constraints.conforming);
      readTin(edges);
      r.constraintsChecked = true;
      r.pieces = edges.pieces();
      r.piecesMissing = edges.piecesMissing();
      r.constraintVerticesMissing = edges.verticesMissing();
      r.heightsDiffering = edges.heightsDiffering();
      r.firstMissingPiece = edges.firstMissing();
      std::vector<WaterFlatnessCheck::Lake> lakes;
      for (const WaterBody& b : constraints.bodies)
        if (!b.river) lakes.push_back({constraints.water[b.area], b.body, b.level, b.source});
      if (!lakes.empty()) {
        WaterFlatnessCheck flat(std::move(lakes));
        readTin(flat);
        r.waterChecked = true;
        r.lakes = flat.bodies();
        r.lakesNotFlat = flat.bodiesNotFlat();
        r.worstLakeSpread = flat.worstSpread();
        r.firstLakeNotFlat = flat.firstNotFlat();
      }
      if (!constraints.bodies.empty()) {
        BankCheck banks(constraints.water, constraints.bodies, constraints.band, constraints.spacing);
        struct Vertices final : MeshSink {
          BankCheck& check;
          explicit Vertices(BankCheck& c) : check(c) {}
          void begin(const MeshInfo&) override {}
          void vertex(std::uint64_t, double x, double y, double z) override { check.sample(x, y, z); }
          void triangle(std::uint64_t, std::uint64_t, std::uint64_t) override {}
          void finalizeVertex(std::uint64_t) override {}
          void end() override {}
        } vertices(banks);
        if (!banks.empty()) {
          readTin(vertices);
          const BankCheckFigures f = banks.figures();
          r.banksChecked = true;
          r.bankVertices = f.samples;
          for (std::size_t i = 0; i < constraints.bodies.size() && i < f.bodyViolations.size(); ++i)
            (constraints.bodies[i].given ? r.bankBelowGiven : r.bankBelowDerived) += f.bodyViolations[i];
          r.worstBank = f.worstAt;
          r.worstBankDerived = f.worstDerivedAt;
        }
      }
    }
    ConcatPointStream stream(in.streams);
    if (!stream.rewindable())
      throw UsageError("verify --points: the inputs must be files (they are read several times)");
    SurveyStatsOptions so;
    so.filter = &fo.filter;
    so.memoryBudget = o.finalizer.memoryBudget;
    const SurveyStats stats = analyzeSurvey(stream, so);
    r.pointsChecked = true;
    r.inputPoints = stats.counts.points;
    r.pointsCountable = stats.duplicatesKnown || stats.counts.points == 0;
    r.inputDuplicates = stats.duplicatesXY;
    r.inputDistinct = stats.distinctXY.count;
    r.pointsMatch = r.pointsCountable && stats.distinctXY == r.check.fingerprint;
  }
  r.seconds = std::chrono::duration<double>(JobClock::now() - t0).count();
  return r;
}

std::string formatVerifyText(const VerifyReport& r) {
  const MeshCheckReport& c = r.check;
  std::string o = r.mesh + ": " + withCommas(c.vertices) + " vertices, " + withCommas(c.triangles) +
                  " triangles, " + withCommas(c.interiorEdges) +
                  " interior edges checked locally Delaunay (exact), " + withCommas(c.hullEdges) +
                  " hull edges; at most " + withCommas(c.maxLiveVertices) + " live vertices and " +
                  withCommas(c.maxOpenEdges) + " open edges; " + formatDouble("%.2f s", r.seconds) + "\n";
  if (c.ok()) {
    o += "  mesh: valid streaming mesh, counter-clockwise, Delaunay, convex hull covered (hull area " +
         formatDouble("%.6g", c.hullArea) + " = sum of triangle areas)\n";
  } else {
    for (const auto& p : c.problems)
      o += "  problem: " + p.kind + " (" + withCommas(p.count) + "x): " + p.first + "\n";
  }
  if (r.pointsChecked) {
    if (!r.pointsCountable)
      o += "  points: could not be compared (the inputs are too incoherent for the memory budget; raise "
           "--memory)\n";
    else if (r.pointsMatch)
      o += "  points: every input point is used: the " + withCommas(r.inputDistinct) + " distinct xy of " +
           withCommas(r.inputPoints) + " input points (after filters; " + withCommas(r.inputDuplicates) +
           " duplicates) are exactly the mesh's vertices\n";
    else
      o += "  points: MISMATCH: the inputs have " + withCommas(r.inputDistinct) + " distinct xy (of " +
           withCommas(r.inputPoints) + " points after filters), the mesh has " + withCommas(c.vertices) +
           " vertices, and the sets differ\n";
  }
  if (r.constraintsChecked) {
    if (r.constraintsOk())
      o += "  constraints: every one of the " + withCommas(r.pieces) +
           " constraint pieces is a TIN edge, every constraint vertex a TIN vertex at its height\n";
    else
      o += "  constraints: PROBLEM: " + withCommas(r.piecesMissing) + " of " + withCommas(r.pieces) +
           " pieces are no TIN edge" + (r.firstMissingPiece.empty() ? "" : " (the first " + r.firstMissingPiece + ")") +
           ", " + withCommas(r.constraintVerticesMissing) + " constraint vertices missing, " +
           withCommas(r.heightsDiffering) + " at another height\n";
  }
  if (r.waterChecked) {
    if (r.lakesNotFlat == 0)
      o += "  water: every one of the " + withCommas(r.lakes) +
           " lakes is flat at its level (largest spread " + formatDouble("%.3g", r.worstLakeSpread) + ")\n";
    else
      o += "  water: PROBLEM: " + withCommas(r.lakesNotFlat) + " of " + withCommas(r.lakes) +
           " lakes are not flat (the first " + r.firstLakeNotFlat + ")\n";
  }
  if (r.banksChecked) {
    if (r.bankBelowDerived == 0 && r.bankBelowGiven == 0)
      o += "  banks: every one of the " + withCommas(r.bankVertices) +
           " TIN vertices within the bank band is at or above the water beside it\n";
    else if (r.bankBelowDerived)
      o += "  banks: PROBLEM: " + withCommas(r.bankBelowDerived) + " of the " + withCommas(r.bankVertices) +
           " TIN vertices within the bank band lie below a level derived from the banks (the worst: " +
           r.worstBankDerived + ")\n";
    if (r.bankBelowGiven)
      o += "  banks: " + withCommas(r.bankBelowGiven) + " of the " + withCommas(r.bankVertices) +
           " TIN vertices within the bank band lie below a level given with its polygon (the worst: " +
           r.worstBank + ")\n";
  }
  o += r.ok() ? "verify: OK\n" : "verify: FAILED\n";
  return o;
}

std::string formatVerifyJson(const VerifyReport& r) {
  const MeshCheckReport& c = r.check;
  JsonWriter j;
  j.beginObject();
  j.key("mesh").value(r.mesh);
  j.key("ok").value(r.ok());
  j.key("vertices").value(c.vertices);
  j.key("triangles").value(c.triangles);
  j.key("interior_edges").value(c.interiorEdges);
  j.key("hull_edges").value(c.hullEdges);
  j.key("hull_area").value(c.hullArea);
  j.key("triangle_area").value(c.triangleArea);
  j.key("max_live_vertices").value(c.maxLiveVertices);
  j.key("max_open_edges").value(c.maxOpenEdges);
  j.key("problems").beginArray();
  for (const auto& p : c.problems) {
    j.beginObject();
    j.key("kind").value(p.kind);
    j.key("first").value(p.first);
    j.key("count").value(p.count);
    j.endObject();
  }
  j.endArray();
  j.key("points");
  if (!r.pointsChecked) {
    j.null();
  } else {
    j.beginObject();
    j.key("input_points").value(r.inputPoints);
    j.key("input_distinct_xy").value(r.inputDistinct);
    j.key("input_duplicates").value(r.inputDuplicates);
    j.key("comparable").value(r.pointsCountable);
    j.key("match").value(r.pointsMatch);
    j.endObject();
  }
  if (r.constraintsChecked) {
    j.key("constraints").beginObject();
    j.key("pieces").value(r.pieces);
    j.key("pieces_not_edges").value(r.piecesMissing);
    j.key("vertices_missing").value(r.constraintVerticesMissing);
    j.key("heights_differing").value(r.heightsDiffering);
    j.endObject();
  }
  if (r.waterChecked) {
    j.key("water").beginObject();
    j.key("lakes").value(r.lakes);
    j.key("lakes_not_flat").value(r.lakesNotFlat);
    j.key("largest_spread").value(r.worstLakeSpread);
    j.endObject();
  }
  if (r.banksChecked) {
    j.key("banks").beginObject();
    j.key("vertices").value(r.bankVertices);
    j.key("below_derived_level").value(r.bankBelowDerived);
    j.key("below_given_level").value(r.bankBelowGiven);
    j.key("worst").value(r.worstBank);
    j.endObject();
  }
  j.key("seconds").value(r.seconds);
  j.endObject();
  return j.str() + "\n";
}

}  // namespace tinbuild
