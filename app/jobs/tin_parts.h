// A TIN written in parts (the mesh manifest FILE.parts.json of a planned or MPI run, formats/io/plan_file.h):
// read as one TIN, joined into one mesh file, described.
#pragma once

#include <string>

#include "app/jobs/job_options.h"
#include "app/jobs/run_report.h"
#include "libterrain/mesh/mesh_sink.h"

namespace tinbuild {

// Reads the TIN of a mesh manifest (its parts and its seam, formats/io/plan_file.h) as one streaming mesh:
// a seam vertex that a part wrote is one vertex, with one id, finalized after the seam's last use.
// Memory: the seam's vertices plus each file's width.
void readMeshParts(const std::string& manifest, MeshSink& out);

// `tinbuild merge FILE.parts.json -o MESH`: the TIN in parts written as one mesh (options.meshOutput: any
// mesh format of `build --mesh`), with the manifest's CRS.
RunReport runJoin(const std::string& manifest, const PipelineOptions& options, Diagnostics& diag);

// `tinbuild info FILE.parts.json`: the TIN in parts, described from its manifest and files' sizes.
std::string formatMeshManifestInfo(const std::string& manifest, bool json);

}  // namespace tinbuild
