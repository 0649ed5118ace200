// commonlight plot CSV --out PNG [--x COLUMN] [--columns A,B,...] [--title T]
//
// Draws the numeric columns of a CSV file (a header row, then numbers; empty or "nan" cells are
// gaps) against one of them, one panel per column, stacked, with each panel's range written at its
// side. scripts/soak draws its samples with it (docs/reliability.md).
//
//   Step 1  read the CSV: header, numeric rows
//   Step 2  one panel per column: its range, grid, the polyline
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "apps/app.h"

namespace commonlight::apps {

namespace {

struct PlotOptions {
    std::string csv;
    std::string out;
    std::string x = "t_s";
    std::vector<std::string> columns;  // empty: every column but x
    std::string title;
};

std::vector<std::string> splitCsv(const std::string& line) {
    std::vector<std::string> cells;
    std::stringstream in(line);
    std::string cell;
    while (std::getline(in, cell, ',')) {
        while (!cell.empty() && (cell.back() == '\r' || cell.back() == ' ')) cell.pop_back();
        cells.push_back(cell);
    }
    if (!line.empty() && line.back() == ',') cells.emplace_back();  // an empty last cell
    return cells;
}

double parseCell(const std::string& cell) {
    if (cell.empty()) return std::numeric_limits<double>::quiet_NaN();
    char* end = nullptr;
    const double v = std::strtod(cell.c_str(), &end);
    return end != nullptr && *end == '\0' ? v : std::numeric_limits<double>::quiet_NaN();
}

std::string fmt(double v) {
    char text[32];
    if (std::abs(v) >= 1000 || v == std::round(v)) {
        std::snprintf(text, sizeof text, "%.0f", v);
    } else {
        std::snprintf(text, sizeof text, "%.3g", v);
    }
    return text;
}

int runPlot(const PlotOptions& options) {
    // Step 1: the CSV.
    std::ifstream in(options.csv);
    if (!in) return reportError(Error{ErrorCode::kIo, options.csv + ": cannot open the file"});
    std::string line;
    if (!std::getline(in, line)) return reportError(Error{ErrorCode::kBadInput, options.csv + ": empty file (no header row)"});
    const std::vector<std::string> header = splitCsv(line);
    std::vector<std::vector<double>> rows;
    std::size_t line_number = 1;
    while (std::getline(in, line)) {
        ++line_number;
        if (line.empty()) continue;
        std::vector<std::string> cells = splitCsv(line);
        if (cells.size() != header.size()) {
            return reportError(Error{ErrorCode::kBadInput, options.csv + ":" + std::to_string(line_number) + ": " + std::to_string(cells.size()) +
                                                               " fields where the header has " + std::to_string(header.size()) +
                                                               " (a truncated row?)"});
        }
        std::vector<double> row(header.size(), std::numeric_limits<double>::quiet_NaN());
        for (std::size_t i = 0; i < std::min(cells.size(), header.size()); ++i) row[i] = parseCell(cells[i]);
        rows.push_back(std::move(row));
    }
    const auto column = [&](const std::string& name) -> std::optional<std::size_t> {
        const auto it = std::find(header.begin(), header.end(), name);
        if (it == header.end()) return std::nullopt;
        return static_cast<std::size_t>(it - header.begin());
    };
    const auto xi = column(options.x);
    if (!xi) return reportError(Error{ErrorCode::kBadInput, options.csv + ": no column '" + options.x + "' (--x)"});
    std::vector<std::size_t> ys;
    if (options.columns.empty()) {
        for (std::size_t i = 0; i < header.size(); ++i) {
            if (i != *xi) ys.push_back(i);
        }
    } else {
        for (const auto& name : options.columns) {
            const auto yi = column(name);
            if (!yi) return reportError(Error{ErrorCode::kBadInput, options.csv + ": no column '" + name + "' (--columns)"});
            ys.push_back(*yi);
        }
    }
    if (rows.empty() || ys.empty()) return reportError(Error{ErrorCode::kBadInput, options.csv + ": no rows or no columns to draw"});

    // Step 2: the panels.
    const int w = 1000, panel_h = 130, left = 190, right = 30, top = options.title.empty() ? 15 : 40, bottom = 45, gap = 12;
    const int h = top + static_cast<int>(ys.size()) * (panel_h + gap) + bottom;
    cv::Mat img(h, w, CV_8UC3, cv::Scalar(255, 255, 255));
    const cv::Scalar black(0, 0, 0), grey(210, 210, 210), blue(180, 80, 20);
    double x_min = std::numeric_limits<double>::infinity(), x_max = -x_min;
    for (const auto& r : rows) {
        if (std::isfinite(r[*xi])) x_min = std::min(x_min, r[*xi]), x_max = std::max(x_max, r[*xi]);
    }
    if (!std::isfinite(x_min)) return reportError(Error{ErrorCode::kBadInput, options.csv + ": column '" + options.x + "' has no numbers"});
    if (x_max <= x_min) x_max = x_min + 1;
    const auto X = [&](double x) { return left + static_cast<int>(std::lround((w - left - right) * (x - x_min) / (x_max - x_min))); };
    if (!options.title.empty()) cv::putText(img, options.title, {8, 27}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black);
    for (std::size_t p = 0; p < ys.size(); ++p) {
        const std::size_t yi = ys[p];
        const int y0 = top + static_cast<int>(p) * (panel_h + gap), y1 = y0 + panel_h;
        double lo = std::numeric_limits<double>::infinity(), hi = -lo;
        for (const auto& r : rows) {
            if (std::isfinite(r[yi]) && std::isfinite(r[*xi])) lo = std::min(lo, r[yi]), hi = std::max(hi, r[yi]);
        }
        cv::rectangle(img, {left, y0}, {w - right, y1}, black);
        cv::putText(img, header[yi], {8, y0 + panel_h / 2 + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.45, black);
        if (!std::isfinite(lo)) {
            cv::putText(img, "no values", {left + 10, y0 + panel_h / 2}, cv::FONT_HERSHEY_SIMPLEX, 0.45, black);
            continue;
        }
        // A flat series sits in the middle of its panel; the range is written at the side.
        const double span = hi > lo ? hi - lo : std::max(1.0, std::abs(lo));
        const double base = hi > lo ? lo - 0.08 * span : lo - 0.5 * span;
        const double range = hi > lo ? 1.16 * span : span;
        const auto Y = [&](double v) { return y1 - static_cast<int>(std::lround(panel_h * (v - base) / range)); };
        for (int k = 1; k < 4; ++k) cv::line(img, {left + 1, y0 + k * panel_h / 4}, {w - right - 1, y0 + k * panel_h / 4}, grey);
        cv::putText(img, fmt(hi), {left - 62, Y(hi) + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.4, black);
        cv::putText(img, fmt(lo), {left - 62, Y(lo) + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.4, black);
        std::optional<cv::Point> previous;
        for (const auto& r : rows) {
            if (!std::isfinite(r[yi]) || !std::isfinite(r[*xi])) {
                previous.reset();
                continue;
            }
            const cv::Point at(X(r[*xi]), Y(r[yi]));
            if (previous) cv::line(img, *previous, at, blue, 2, cv::LINE_AA);
            cv::circle(img, at, 2, blue, cv::FILLED);
            previous = at;
        }
    }
    for (int k = 0; k <= 5; ++k) {
        const double x = x_min + (x_max - x_min) * k / 5;
        cv::putText(img, fmt(x), {X(x) - 12, h - bottom + 18}, cv::FONT_HERSHEY_SIMPLEX, 0.45, black);
    }
    cv::putText(img, options.x, {left + (w - left - right) / 2 - 20, h - 8}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black);
    try {
        if (!cv::imwrite(options.out, img)) return reportError(Error{ErrorCode::kIo, options.out + ": cannot write the PNG"});
    } catch (const cv::Exception& e) {
        return reportError(Error{ErrorCode::kIo, options.out + ": cannot write the PNG: " + e.what()});
    }
    std::printf("plot: %s (%zu rows, %zu panels)\n", options.out.c_str(), rows.size(), ys.size());
    return kExitOk;
}

}  // namespace

void addPlotCommand(CLI::App& app, Runner& runner) {
    auto options = std::make_shared<PlotOptions>();
    CLI::App* sub = app.add_subcommand("plot", "Draw a CSV's numeric columns against one of them (PNG; scripts/soak)");
    sub->add_option("csv", options->csv, "CSV file with a header row")->required();
    sub->add_option("--out", options->out, "PNG to write")->required();
    sub->add_option("--x", options->x, "The column along x")->capture_default_str();
    sub->add_option("--columns", options->columns, "The columns to draw, one panel each (default: all but --x)")->delimiter(',');
    sub->add_option("--title", options->title, "A title above the panels");
    sub->footer("Exit codes: 0 ok, 2 usage, 3 bad input");
    sub->callback([options, &runner] { runner = [options] { return runPlot(*options); }; });
}

}  // namespace commonlight::apps
