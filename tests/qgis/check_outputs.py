#!/usr/bin/python3
"""Opens tinbuild's outputs in QGIS, headless, the way a GIS analyst would: the DEM (GeoTIFF tiles
under a VRT, and the GeoTIFF), the GeoPackage TIN and the contour lines (vector layers with their
spatial index) and the UGRID
NetCDF mesh (a mesh layer through MDAL).  Each must be valid, carry the survey's CRS and hold what the
run report says (features, faces, vertices).

    QT_QPA_PLATFORM=offscreen /usr/bin/python3 tests/qgis/check_outputs.py --tinbuild build/tinbuild

It makes its own survey (`tinbuild demo --survey-only`, 1M points, EPSG:32610) in a scratch folder
and builds every output from it.  Exit 0: all checks hold; 1: a check failed (each failure printed);
77: QGIS's Python bindings are not installed (Debian: python3-qgis), which CTest reports as skipped.
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

SKIP = 77


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tinbuild", required=True, help="the tinbuild executable")
    ap.add_argument("--workdir", help="scratch folder (default: a new temporary one, removed afterwards)")
    ap.add_argument("--points", default="1", help="survey size in millions of points")
    args = ap.parse_args()

    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    try:
        from qgis.core import (QgsApplication, QgsCoordinateReferenceSystem, QgsFeatureSource,
                               QgsMeshLayer, QgsRasterLayer, QgsRectangle, QgsVectorLayer,
                               QgsFeatureRequest)
    except ImportError as e:
        print(f"skipped: QGIS's Python bindings are not installed ({e}); apt-get install python3-qgis")
        return SKIP

    work = args.workdir or tempfile.mkdtemp(prefix="tinbuild-qgis-")
    os.makedirs(work, exist_ok=True)
    failures = []

    def check(ok, what):
        print(("ok    " if ok else "FAIL  ") + what)
        if not ok:
            failures.append(what)

    def run(cmd):
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            print(" ".join(cmd), "\n", r.stdout, r.stderr)
            raise SystemExit(1)

    try:
        demo = os.path.join(work, "demo")
        shutil.rmtree(demo, ignore_errors=True)
        run([args.tinbuild, "demo", demo, "--points", args.points, "--survey-only", "--progress", "none"])
        survey = os.path.join(demo, "survey.laz")
        out = os.path.join(work, "out")
        shutil.rmtree(out, ignore_errors=True)
        os.makedirs(out)
        report = os.path.join(out, "report.json")
        run([args.tinbuild, "build", survey, "--keep-class", "2,9", "-q", "--overwrite",
             "--mesh", os.path.join(out, "tin.nc"), "--gpkg", os.path.join(out, "tin.gpkg"),
             "--dem", os.path.join(out, "dem"), "--step", "1", "--report", report,
             "--contours", os.path.join(out, "contours.gpkg"), "--interval", "1", "--index-every", "5"])
        run([args.tinbuild, "build", survey, "--keep-class", "2,9", "-q", "--overwrite",
             "--dem", os.path.join(out, "dem.tif"), "--step", "2"])
        # Hydro-flattened: the demo's river polygon and centreline, its road's crest as a breakline.
        water, flow, roads = (os.path.join(demo, n) for n in ("water.geojson", "flow.geojson", "roads.geojson"))
        run([args.tinbuild, "build", survey, "--keep-class", "2,9", "-q", "--overwrite",
             "--water", water, "--flow", flow, "--breaklines", roads,
             "--dem", os.path.join(out, "hydro.tif"), "--step", "1", "--gpkg", os.path.join(out, "hydro.gpkg")])
        rep = json.load(open(report))
        triangles = rep["triangulation"]["triangles"]
        vertices = rep["triangulation"]["vertices"]
        contourLines = rep["contours"]["lines"]
        want = QgsCoordinateReferenceSystem("EPSG:32610")

        QgsApplication.setPrefixPath("/usr", True)
        app = QgsApplication([], False)
        app.initQgis()

        def checkLayers():
            # (The layers live in this function only: they must be gone before exitQgis().)
            # The DEM: the VRT over the tiles, and a single GeoTIFF.
            for name in ("dem/mosaic.vrt", "dem.tif"):
                layer = QgsRasterLayer(os.path.join(out, name), name, "gdal")
                check(layer.isValid(), f"DEM {name} opens as a raster layer")
                if layer.isValid():
                    check(layer.crs() == want, f"DEM {name} CRS {layer.crs().authid()} is EPSG:32610")
                    stats = layer.dataProvider().bandStatistics(1)
                    check(stats.maximumValue > stats.minimumValue,
                          f"DEM {name} has elevations ({stats.minimumValue:.2f} .. {stats.maximumValue:.2f})")

            # The GeoPackage TIN.
            tin = QgsVectorLayer(os.path.join(out, "tin.gpkg") + "|layername=tin", "tin", "ogr")
            check(tin.isValid(), "tin.gpkg layer tin opens as a vector layer")
            if tin.isValid():
                check(tin.crs() == want, f"tin.gpkg CRS {tin.crs().authid()} is EPSG:32610")
                check(tin.featureCount() == triangles,
                      f"tin.gpkg holds {tin.featureCount()} triangles, the report {triangles}")
                check(tin.dataProvider().hasSpatialIndex() == QgsFeatureSource.SpatialIndexPresent,
                      "tin.gpkg has its spatial index")
                e = tin.extent()
                window = QgsRectangle(e.xMinimum() + 0.4 * e.width(), e.yMinimum() + 0.4 * e.height(),
                                      e.xMinimum() + 0.45 * e.width(), e.yMinimum() + 0.45 * e.height())
                hits = sum(1 for _ in tin.getFeatures(QgsFeatureRequest().setFilterRect(window)))
                check(hits > 0, f"a spatial query finds {hits} triangles in a small window")
                f = next(tin.getFeatures())
                g = f.geometry()
                check(g.constGet().is3D() and g.constGet().vertexCount() == 4,
                      f"a feature is a 3D triangle ring ({g.asWkt(3)[:60]}...)")

            # The contour lines.
            iso = QgsVectorLayer(os.path.join(out, "contours.gpkg") + "|layername=contours", "contours", "ogr")
            check(iso.isValid(), "contours.gpkg opens as a vector layer")
            if iso.isValid():
                check(iso.crs() == want, f"contours.gpkg CRS {iso.crs().authid()} is EPSG:32610")
                check(iso.featureCount() == contourLines,
                      f"contours.gpkg holds {iso.featureCount()} lines, the report {contourLines}")
                check(iso.dataProvider().hasSpatialIndex() == QgsFeatureSource.SpatialIndexPresent,
                      "contours.gpkg has its spatial index")

            # The UGRID mesh.
            mesh = QgsMeshLayer(os.path.join(out, "tin.nc"), "tin", "mdal")
            check(mesh.isValid(), "tin.nc opens as a mesh layer")
            if mesh.isValid():
                dp = mesh.dataProvider()
                check(mesh.crs() == want, f"tin.nc CRS {mesh.crs().authid()} is EPSG:32610")
                check(dp.faceCount() == triangles, f"tin.nc has {dp.faceCount()} faces, the report {triangles}")
                check(dp.vertexCount() == vertices,
                      f"tin.nc has {dp.vertexCount()} vertices, the report {vertices}")
                groups = [dp.datasetGroupMetadata(i).name() for i in range(dp.datasetGroupCount())]
                check(len(groups) > 0, f"tin.nc has elevations on its vertices (dataset groups {groups})")

        def checkHydro():
            from qgis.core import QgsPointXY
            dem = QgsRasterLayer(os.path.join(out, "hydro.tif"), "hydro", "gdal")
            check(dem.isValid(), "the hydro-flattened DEM opens as a raster layer")
            if dem.isValid():
                check(dem.crs() == want, f"hydro.tif CRS {dem.crs().authid()} is EPSG:32610")
            for name, path, kind in (("water polygons", water, "Polygon"), ("breaklines", roads, "Line"),
                                     ("centreline", flow, "Line")):
                layer = QgsVectorLayer(path, name, "ogr")
                check(layer.isValid() and layer.featureCount() == 1, f"the {name} open as a vector layer")
                if layer.isValid():
                    check(layer.crs() == want, f"the {name}' CRS {layer.crs().authid()} is EPSG:32610")
            tin = QgsVectorLayer(os.path.join(out, "hydro.gpkg") + "|layername=tin", "tin", "ogr")
            check(tin.isValid() and tin.crs() == want, "the hydro-flattened TIN opens with its CRS")
            if dem.isValid():
                # Along the centreline, inside the area, the river never rises downstream.
                line = QgsVectorLayer(flow, "flow", "ogr")
                g = next(line.getFeatures()).geometry()
                e = dem.extent()
                values = []
                length = g.length()
                d = 0.0
                while d < length:
                    p = g.interpolate(d).asPoint()
                    if e.xMinimum() + 10 < p.x() < e.xMaximum() - 10:
                        v, ok = dem.dataProvider().sample(QgsPointXY(p), 1)
                        if ok:
                            values.append(v)
                    d += 1.0
                rises = sum(1 for a, b in zip(values, values[1:]) if b > a + 1e-4)
                check(len(values) > 100 and rises == 0,
                      f"the river never rises along its centreline ({len(values)} samples, {rises} rises)")

        checkLayers()
        checkHydro()
        app.exitQgis()
    finally:
        if not args.workdir:
            shutil.rmtree(work, ignore_errors=True)

    print(f"{len(failures)} failed" if failures else "all QGIS checks passed")
    return 1 if failures else 0


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    # PyQGIS may crash while the interpreter tears its objects down after exitQgis(); the checks are
    # done and reported, so leave without that teardown.
    os._exit(code)
