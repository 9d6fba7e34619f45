// The survey files a command line names: files, directories and glob patterns.
//
// A survey is usually hundreds of tiles, and batch systems pass patterns quoted (so no shell expands
// them) or directories.  expandInputs turns the command line's input words into the list of files, in a
// deterministic order (the order of the words; within a directory or pattern, by name in byte order), so
// the same command always reads the same sequence:
//   -            stdin, as it is;
//   DIR          every regular file in DIR (not recursive) whose extension a reader row lists
//                (formats/registry/reader_registry.h: *.las, *.laz, *.xyz, any case);
//   PATTERN      a word with * ? or [ that is not an existing file: glob(3); a matched directory is
//                expanded as DIR;
//   FILE         as it is (a missing file is reported by the reader, naming it).
// Errors (DataError naming the word): a directory with no survey file, a pattern matching nothing, and
// the same file named twice (its points would be counted twice).
#pragma once

#include <string>
#include <vector>

namespace tinbuild {

std::vector<std::string> expandInputs(const std::vector<std::string>& words);

}  // namespace tinbuild
