// For tests that run Aravis (GigE Vision) over loopback: Aravis discovery broadcasts on every
// interface, so such a test must run in a private network namespace holding only loopback.
// requirePrivateNetwork() re-executes the test binary under `unshare -n` (once), brings lo up,
// and exits 77 (skip) with a message when a namespace cannot be made.
#pragma once

#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

namespace commonlight::testing {

inline void requirePrivateNetwork() {
    constexpr const char* kMarker = "COMMONLIGHT_IN_PRIVATE_NETNS";
    if (std::getenv(kMarker) != nullptr) {
        if (std::system("ip link set lo up") != 0) {
            std::fprintf(stderr, "SKIP: cannot bring lo up in the private network namespace\n");
            std::_Exit(77);
        }
        return;
    }
    if (std::system("unshare -n true >/dev/null 2>&1") != 0) {
        std::fprintf(stderr, "SKIP: unshare -n is not permitted here (needs CAP_SYS_ADMIN or user namespaces)\n");
        std::_Exit(77);
    }
    std::ifstream cmdline("/proc/self/cmdline", std::ios::binary);
    const std::string all((std::istreambuf_iterator<char>(cmdline)), std::istreambuf_iterator<char>());
    std::vector<std::string> args{"unshare", "-n", "--", "/proc/self/exe"};
    std::size_t start = all.find('\0');  // skip argv[0]
    while (start != std::string::npos && start + 1 < all.size()) {
        const std::size_t end = all.find('\0', start + 1);
        args.push_back(all.substr(start + 1, end - start - 1));
        start = end;
    }
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    setenv(kMarker, "1", 1);
    // /proc/self/exe is resolved by unshare in the same mount namespace: this very binary.
    char exe[4096];
    const ssize_t n = readlink("/proc/self/exe", exe, sizeof(exe) - 1);
    if (n > 0) {
        exe[n] = '\0';
        args[3] = exe;
        argv[3] = args[3].data();
    }
    execvp("unshare", argv.data());
    std::perror("execvp unshare");
    std::_Exit(77);
}

}  // namespace commonlight::testing
