// The README's library example (examples/locate.cpp): the code README shows is the code that is built, and it
// runs: it locates the workpiece of a simulated cell where its truth puts it, and registers the first scan.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cstdlib>
#include <nlohmann/json.hpp>
#include <string>

#include "test_util.hpp"

namespace fs = std::filesystem;
using partloc::test::slurp;

namespace {

/// The lines between `begin` and `end` in `text`, each with its leading spaces removed.
std::string block(const std::string& text, const std::string& begin, const std::string& end) {
    const auto a = text.find(begin), b = text.find(end);
    if (a == std::string::npos || b == std::string::npos || b < a) return "";
    std::istringstream in(text.substr(a + begin.size(), b - a - begin.size()));
    std::string line, out;
    while (std::getline(in, line)) {
        const auto first = line.find_first_not_of(' ');
        if (first != std::string::npos) out += line.substr(first) + "\n";
    }
    return out;
}

int run(const std::string& cmd) {
    const int status = std::system(cmd.c_str());
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

}  // namespace

TEST(LibraryExample, ReadmeShowsTheExampleThatIsBuilt) {
    const std::string example =
        block(slurp(PARTLOC_SOURCE_DIR "/examples/locate.cpp"), "// [readme]\n", "// [/readme]");
    const std::string readme =
        block(slurp(PARTLOC_SOURCE_DIR "/README.md"), "```cpp\n", "```\n<!-- /LIBRARY-EXAMPLE -->");
    ASSERT_FALSE(example.empty());
    EXPECT_NE(readme.find(example), std::string::npos)
        << "README's example differs from examples/locate.cpp:\n"
        << readme << "\n---\n"
        << example;
}

TEST(LibraryExample, LocatesASimulatedCell) {
    partloc::test::TempFolder tmp("partloc_example");
    const fs::path cell = tmp.dir / "cell", out = tmp.dir / "out", said = tmp.dir / "stdout.txt";
    ASSERT_EQ(run("'" PARTLOC_EXE "' simulate --out '" + cell.string() + "' --seed 3 > /dev/null"), 0);
    ASSERT_EQ(run("'" PARTLOC_EXAMPLE_EXE "' '" + (cell / "job.yaml").string() + "' '" + out.string() +
                  "' > '" + said.string() + "' 2>&1"),
              0)
        << slurp(said);
    const std::string text = slurp(said);
    EXPECT_NE(text.find("scans/scan_01.ply: registered"), std::string::npos) << text;
    const auto truth = nlohmann::json::parse(slurp(cell / "truth.json"));
    const auto result = nlohmann::json::parse(slurp(out / "result.json"));
    ASSERT_EQ(result["status"], "located");
    const auto& M = truth["workpiece"]["T_machine_workpiece"];
    const auto& o = result["workpiece"]["origin"];
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(o[k].get<double>(), M[k][3].get<double>(), 0.05) << k;
    EXPECT_NE(text.find("located: origin"), std::string::npos) << text;
}
