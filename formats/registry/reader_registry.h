// The table of point-cloud readers: an input is recognised once, by its content, never by its name.
//
// openPointReader() reads the first bytes of an input (kSniffBytes, or fewer when the input is shorter;
// stdin's are pushed back for the reader) and gives them to each row's recognises() in table order; the
// first row that claims them opens the reader.  The order matters: COPC is LAZ is LAS by signature, so
// the most specific comes first:
//   COPC  "LASF", and the first VLR (right after a LAS 1.4 header) is the COPC info VLR ("copc", 1)
//   LAZ   "LASF", and the point format's compression bits (0x80 / 0x40) are set
//   LAS   "LASF"
//   XYZ   anything else (text: the reader sniffs its columns)
// A LAZ that forgot its compression bits is still caught by the LAS reader, which finds the "laszip
// encoded" VLR.  Adding a format is one row here (reader_registry.cpp) and one file for its reader.
// --a_srs is applied here, to every reader alike, by a wrapper that replaces the CRS it reports.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "formats/pointcloud/point_reader.h"

namespace tinbuild {

class Diagnostics;

struct ReaderRow {
  const char* format;      // "COPC", "LAZ", "LAS", "XYZ"
  const char* extensions;  // the file name endings a survey directory lists for it, "|"-separated ("laz")
  // True when an input starting with `head` (its first `size` bytes, at most kSniffBytes) is this format.
  bool (*recognises)(const std::uint8_t* head, std::size_t size);
  std::unique_ptr<PointReader> (*open)(const std::string& path, const ReaderOptions& options,
                                       Diagnostics& diag);
};

// Bytes read from an input to recognise it: a LAS 1.4 header (375) and the header of its first VLR.
constexpr std::size_t kSniffBytes = 512;

// Every reader, in the order they are tried.
const std::vector<ReaderRow>& readerTable();

// Whether a directory listing takes this file name as a survey file: its extension (any case) is one of a
// row's (formats/registry/input_list.h).  Recognition itself never looks at the name.
bool isSurveyFileName(const std::string& name);

// The rows' extensions for messages: ".las, .laz or .xyz".
std::string surveyExtensionsText();

// The row that recognises these first bytes (the last row, XYZ, takes anything).
const ReaderRow& recogniseInput(const std::uint8_t* head, std::size_t size);

// Opens any supported input by content.  "-" reads stdin.  Throws DataError naming the file when it
// cannot be read.
std::unique_ptr<PointReader> openPointReader(const std::string& path, const ReaderOptions& options,
                                             Diagnostics& diag);

}  // namespace tinbuild
