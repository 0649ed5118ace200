#include "core/csv.h"

#include <charconv>
#include <cmath>

#include "core/file_util.h"

namespace commonlight::csv {

namespace {

std::string_view trim(std::string_view s) {
    while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
    while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r')) s.remove_suffix(1);
    return s;
}

Error cellError(const std::filesystem::path& file, const Row& row, std::string_view column, std::string_view problem) {
    std::string msg = file.string() + ":" + std::to_string(row.line) + ": column '" + std::string(column) + "': ";
    msg += problem;
    return Error{ErrorCode::kBadInput, std::move(msg)};
}

}  // namespace

Result<std::vector<Row>> read(const std::filesystem::path& file, std::size_t min_columns) {
    CL_TRY(const std::string text, readTextFile(file));
    std::vector<Row> rows;
    int line_number = 0;
    std::size_t pos = 0;
    while (pos < text.size()) {
        std::size_t eol = text.find('\n', pos);
        const bool last_without_newline = eol == std::string::npos;
        if (last_without_newline) eol = text.size();
        const std::string_view line = trim(std::string_view(text).substr(pos, eol - pos));
        pos = eol + 1;
        ++line_number;
        if (line.empty() || line.front() == '#') continue;
        Row row;
        row.line = line_number;
        std::size_t start = 0;
        while (true) {
            const std::size_t comma = line.find(',', start);
            row.fields.emplace_back(trim(line.substr(start, comma == std::string_view::npos ? line.npos : comma - start)));
            if (comma == std::string_view::npos) break;
            start = comma + 1;
        }
        if (row.fields.size() < min_columns) {
            std::string msg = file.string() + ":" + std::to_string(line_number) + ": expected " +
                              std::to_string(min_columns) + " columns, found " + std::to_string(row.fields.size());
            if (last_without_newline) msg += " (the file looks truncated)";
            return fail(ErrorCode::kBadInput, std::move(msg));
        }
        rows.push_back(std::move(row));
    }
    return rows;
}

Result<std::int64_t> toInt64(const std::filesystem::path& file, const Row& row, std::size_t index,
                             std::string_view column) {
    if (index >= row.fields.size()) return fail(cellError(file, row, column, "missing"));
    const std::string& s = row.fields[index];
    std::int64_t value = 0;
    const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), value);
    if (ec != std::errc() || ptr != s.data() + s.size() || s.empty()) {
        return fail(cellError(file, row, column, "expected an integer, found '" + s + "'"));
    }
    return value;
}

Result<double> toDouble(const std::filesystem::path& file, const Row& row, std::size_t index,
                        std::string_view column) {
    if (index >= row.fields.size()) return fail(cellError(file, row, column, "missing"));
    const std::string& s = row.fields[index];
    double value = 0.0;
    const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), value);
    if (ec != std::errc() || ptr != s.data() + s.size() || s.empty()) {
        return fail(cellError(file, row, column, "expected a number, found '" + s + "'"));
    }
    if (!std::isfinite(value)) return fail(cellError(file, row, column, "must be finite, found '" + s + "'"));
    return value;
}

}  // namespace commonlight::csv
