// report.html in a real headless browser (Debian's Chromium, installed by scripts/install-deps.sh): the page
// loads without a script error, its 3D view draws, and a screenshot of the view is not blank (issue 27).
#include <gtest/gtest.h>
#include <open3d/io/ImageIO.h>

#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <regex>
#include <string>

#include "test_util.hpp"

namespace fs = std::filesystem;
using namespace partloc;

namespace {

fs::path chromium() {
    if (const char* env = std::getenv("PARTLOC_CHROMIUM")) return env;
    for (const char* p : {"/usr/bin/chromium", "/usr/bin/chromium-browser"})
        if (fs::exists(p)) return p;
    return {};
}

/// Chromium without a display, a sandbox (root in CI) or a GPU: WebGL by SwiftShader.
std::string browser(const fs::path& exe, const fs::path& profile) {
    return "timeout 120 '" + exe.string() + "' --headless --no-sandbox --disable-gpu-sandbox " +
           "--enable-unsafe-swiftshader --use-angle=swiftshader --no-first-run --disable-extensions " +
           "--user-data-dir='" + profile.string() + "' --window-size=1200,2400 ";
}

}  // namespace

TEST(ReportBrowser, TheThreeDViewLoadsAndDraws) {
    const fs::path exe = chromium();
    ASSERT_FALSE(exe.empty())
        << "Chromium is not installed (scripts/install-deps.sh installs Debian's chromium)";
    test::TempFolder tmp("partloc_report_browser");
    const fs::path cell = tmp.dir / "cell", out = tmp.dir / "out", log = tmp.dir / "log.txt";
    ASSERT_EQ(
        test::shell("'" PARTLOC_EXE "' simulate --out '" + cell.string() + "' --seed 3 > /dev/null 2>&1"), 0);
    ASSERT_EQ(test::shell("PARTLOC_CACHE='" + (tmp.dir / "cache").string() + "' '" PARTLOC_EXE "' run '" +
                          (cell / "job.yaml").string() + "' --out '" + out.string() + "' --threads 2 > '" +
                          log.string() + "' 2>&1"),
              0)
        << test::slurp(log);
    const auto result = nlohmann::json::parse(test::slurp(out / "result.json"));
    ASSERT_TRUE(result.contains("allowance")) << "the simulated job has a final part: its allowance is drawn";
    const std::string page = test::slurp(out / "report.html");
    ASSERT_NE(page.find("id=view3d-data"), std::string::npos) << "no 3D view in the report";
    EXPECT_EQ(page.find("No 3D view"), std::string::npos);

    // The DOM once the scripts ran: #view3d says how many pixels its first frame drew, or the error.
    const fs::path dom = tmp.dir / "dom.html", err = tmp.dir / "chromium.txt";
    ASSERT_EQ(
        test::shell(browser(exe, tmp.dir / "profile1") + "--dump-dom 'file://" +
                    (out / "report.html").string() + "' > '" + dom.string() + "' 2> '" + err.string() + "'"),
        0)
        << test::slurp(err);
    const std::string after = test::slurp(dom);
    std::smatch m;
    const std::regex view("<div[^>]*id=\"view3d\"[^>]*>");
    ASSERT_TRUE(std::regex_search(after, m, view)) << after.substr(0, 2000);
    const std::string tag = m.str();
    EXPECT_EQ(tag.find("data-error"), std::string::npos) << tag;
    std::smatch drawn;
    ASSERT_TRUE(std::regex_search(tag, drawn, std::regex("data-drawn=\"([0-9]+)\""))) << tag;
    EXPECT_GT(std::stol(drawn[1].str()), 10000) << tag;
    std::smatch rect;
    ASSERT_TRUE(std::regex_search(tag, rect, std::regex("data-rect=\"([0-9]+) ([0-9]+) ([0-9]+) ([0-9]+)\"")))
        << tag;
    const int left = std::stoi(rect[1].str()), top = std::stoi(rect[2].str());
    const int width = std::stoi(rect[3].str()), height = std::stoi(rect[4].str());
    ASSERT_GT(width, 300);
    ASSERT_GT(height, 200);

    // A screenshot of the page, tall enough to hold the view where the DOM says it is: inside the canvas,
    // pixels of the first scan's colour (the scan points) and of the allowance's green to blue.
    const fs::path png = tmp.dir / "view.png";
    ASSERT_EQ(
        test::shell(browser(exe, tmp.dir / "profile2") + "--hide-scrollbars --screenshot='" + png.string() +
                    "' 'file://" + (out / "report.html").string() + "' > '" + err.string() + "' 2>&1"),
        0)
        << test::slurp(err);
    open3d::geometry::Image image;
    ASSERT_TRUE(open3d::io::ReadImage(png.string(), image)) << png;
    ASSERT_GE(image.num_of_channels_, 3);
    ASSERT_LE(left + width, image.width_) << png;
    ASSERT_LE(top + height, image.height_) << png;
    long scan_colour = 0, allowance_colour = 0, not_white = 0, inside = 0;
    for (int y = top + 2; y < top + height - 2; ++y)
        for (int x = left + 2; x < left + width - 2; ++x) {
            const unsigned char* p = image.data_.data() + (static_cast<std::size_t>(y) * image.width_ + x) *
                                                              image.num_of_channels_;
            const int r = p[0], g = p[1], b = p[2];
            ++inside;
            if (r < 245 || g < 245 || b < 245) ++not_white;
            if (std::abs(r - 31) < 25 && std::abs(g - 120) < 25 && std::abs(b - 181) < 25) ++scan_colour;
            if (r < 60 && g > 30 && b > 30 && (g > 120 || b > 120)) ++allowance_colour;
        }
    EXPECT_GT(not_white, inside / 50) << "the 3D view looks blank: " << png;
    EXPECT_GT(scan_colour, 200) << "no scan points in the screenshot: " << png;
    EXPECT_GT(allowance_colour, 200) << "no allowance map in the screenshot: " << png;
}
