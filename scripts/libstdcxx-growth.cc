// How libstdc++'s std::unordered_map orders integer keys, for src/sfm/colmap_model.rs (COLMAP
// keeps its cameras, images and points in such maps and writes them in their order).
//
//   g++ -O1 -o growth scripts/libstdcxx-growth.cc
//   ./growth            the bucket counts a map grows through, inserted one key at a time:
//                       "ELEMENT BUCKETS" (the element whose insertion grows it, the new count)
//   ./growth --order K1 K2 ...   the iteration order after inserting K1, K2, ... in this order
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <unordered_map>

int main(int argc, char** argv) {
  if (argc > 1 && std::strcmp(argv[1], "--order") == 0) {
    std::unordered_map<unsigned long, int> map;
    for (int k = 2; k < argc; ++k) map.emplace(std::strtoul(argv[k], nullptr, 10), k);
    for (const auto& kv : map) std::printf("%lu ", kv.first);
    std::printf("\n");
    return 0;
  }
  std::__detail::_Prime_rehash_policy policy;
  std::size_t buckets = 1, elements = 0;
  while (elements < (std::size_t(1) << 32)) {
    auto r = policy._M_need_rehash(buckets, elements, 1);
    if (r.first) {
      buckets = r.second;
      std::printf("%zu %zu\n", elements + 1, buckets);
    }
    // The next insertion that may grow the map.
    std::size_t next = policy._M_state();
    elements = next > elements ? next : elements + 1;
  }
}
