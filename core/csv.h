// CSV reading with line numbers, for data.csv, meta.csv and pose files.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "core/result.h"

namespace commonlight::csv {

struct Row {
    int line = 0;                     // 1-based line in the file
    std::vector<std::string> fields;  // trimmed of spaces
};

// Reads a comma-separated file. Lines starting with '#' and blank lines are skipped; "\r\n" is
// accepted. Every row must have at least `min_columns` fields, else the error names file:line.
Result<std::vector<Row>> read(const std::filesystem::path& file, std::size_t min_columns);

// Strict number parsing; errors read "<file>:<line>: column '<column>': expected ..., found '...'".
Result<std::int64_t> toInt64(const std::filesystem::path& file, const Row& row, std::size_t index,
                             std::string_view column);
Result<double> toDouble(const std::filesystem::path& file, const Row& row, std::size_t index,
                        std::string_view column);

}  // namespace commonlight::csv
