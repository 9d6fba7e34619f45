// The demo's build, as the words a user would type after `tinbuild build`: parsed by the build's own
// option table (parseBuildWords), and recorded in the outputs as those same words, so the options the
// demo runs with and the command its outputs record cannot drift apart.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace tinbuild::app {

// A bare-earth model of the survey `las` (ground and water returns only, what floodplain mapping wants),
// hydro-flattened (the river's polygon and centreline, the road's crest as a breakline: writeDemoFeatures):
// the TIN as a streaming mesh and a GeoPackage, 1 m contours with every 5th an index contour, and a 1 m
// DEM in 512-pixel tiles with its hillshade, all in `dir`.  --overwrite: the demo directory is the demo's
// own, so a second run replaces its outputs (a run-only option: the outputs do not record it).
inline std::vector<std::string> demoBuildWords(const std::string& las, const std::filesystem::path& dir) {
  // clang-format off
  return {las,
          "--keep-class", "2,9",
          "--mesh", (dir / "tin.smb").string(),
          "--gpkg", (dir / "tin.gpkg").string(),
          "--dem", (dir / "dem").string(), "--step", "1", "--tile-size", "512", "--hillshade",
          "--contours", (dir / "contours.gpkg").string(), "--interval", "1", "--index-every", "5",
          "--water", (dir / "water.geojson").string(), "--flow", (dir / "flow.geojson").string(),
          "--breaklines", (dir / "roads.geojson").string(),
          "--overwrite"};
  // clang-format on
}

}  // namespace tinbuild::app
