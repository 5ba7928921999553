#include "sim/flat_map.h"

#include <doctest/doctest.h>

#include <cstdint>
#include <map>
#include <random>
#include <set>
#include <vector>

using namespace dvx;

namespace {

// Every live entry visited exactly once, nothing else; get/contains agree with the reference.
template <typename Map>
void check_equal(const Map& m, const std::map<uint64_t, uint32_t>& ref) {
  REQUIRE(m.size() == ref.size());
  std::map<uint64_t, uint32_t> seen;
  bool twice = false;
  m.for_each([&](uint64_t k, uint32_t v) {
    if (!seen.emplace(k, v).second) twice = true;
  });
  CHECK_FALSE(twice);
  CHECK(seen == ref);
  size_t wrong = 0;  // one assertion for the whole table keeps the churn test fast
  for (const auto& [k, v] : ref) wrong += !m.contains(k) || m.get(k, 7u) != v;
  CHECK(wrong == 0);
  // Load factor stays at most 3/4, so probing always ends on an empty slot.
  CHECK(uint64_t(m.size()) * 4 <= m.capacity() * 3);
}

}  // namespace

TEST_SUITE("flat_map") {
  TEST_CASE("set, get, overwrite, erase basics") {
    FlatMap m;
    CHECK(m.size() == 0);
    CHECK(m.get(5) == ~0u);
    CHECK(m.get(5, 42u) == 42u);
    CHECK_FALSE(m.contains(5));
    CHECK_FALSE(m.erase(5));
    m.set(5, 1);
    m.set(0, 2);  // key 0 is an ordinary key
    CHECK(m.size() == 2);
    CHECK(m.get(5) == 1);
    CHECK(m.get(0) == 2);
    m.set(5, 9);  // overwrite keeps the size
    CHECK(m.size() == 2);
    CHECK(m.get(5) == 9);
    CHECK(m.erase(5));
    CHECK_FALSE(m.erase(5));
    CHECK_FALSE(m.contains(5));
    CHECK(m.get(5, 3u) == 3u);
    CHECK(m.size() == 1);
    m.set(FlatMap::kEmpty - 1, 4);  // largest valid key
    CHECK(m.get(FlatMap::kEmpty - 1) == 4);
    m.clear();
    CHECK(m.size() == 0);
    CHECK_FALSE(m.contains(0));
    m.set(0, 6);
    CHECK(m.get(0) == 6);
  }

  TEST_CASE("heavy churn against std::map (backward-shift erase, wrap-around clusters)") {
    // Small key universes keep the table small and nearly full (load up to 3/4), so probe chains
    // are long and wrap around the end of the table: every backward-shift case is hit.
    std::mt19937_64 rng(20240601);
    for (uint64_t universe : {13ull, 24ull, 40ull, 100ull, 1000ull, 100000ull}) {
      CAPTURE(universe);
      FlatMap m(4);
      std::map<uint64_t, uint32_t> ref;
      uint64_t erased = 0, overwritten = 0;
      for (int op = 0; op < 200000; ++op) {
        const uint64_t r = rng();
        // Spread keys: dense ids, ids times a large power of two, and random 64-bit keys.
        const uint64_t id = r % universe;
        const uint64_t key = (r >> 62) == 0 ? id : (r >> 62) == 1 ? (id << 40) | 3 : id * 0x9e3779b97f4a7c15ull;
        const uint32_t value = uint32_t(r >> 20);
        const int what = int((r >> 8) % 8);
        if (what < 4) {
          if (ref.count(key)) ++overwritten;
          m.set(key, value);
          ref[key] = value;
        } else if (what < 7) {
          const bool had = ref.erase(key) == 1;
          CHECK(m.erase(key) == had);
          erased += had;
        } else {
          auto it = ref.find(key);
          CHECK(m.contains(key) == (it != ref.end()));
          CHECK(m.get(key, 0xdeadu) == (it != ref.end() ? it->second : 0xdeadu));
        }
        REQUIRE(m.size() == ref.size());
        if (op % (universe <= 1000 ? 997 : 49999) == 0) check_equal(m, ref);  // full scans cost O(size)
      }
      check_equal(m, ref);
      CHECK(erased > 10000);
      CHECK(overwritten > 1000);
      // Erase everything: the table ends empty with every lookup failing.
      for (const auto& [k, v] : ref) CHECK(m.erase(k));
      CHECK(m.size() == 0);
      int visited = 0;
      m.for_each([&](uint64_t, uint32_t) { ++visited; });
      CHECK(visited == 0);
      for (const auto& [k, v] : ref) CHECK_FALSE(m.contains(k));
    }
  }

  TEST_CASE("grouped maps (a group's keys share a window of slots) against std::map under churn") {
    // Keys as the surface makes them: groups of consecutive keys (a voxel's patches 0..n-1 with n
    // mostly 1-3, up to 12; an edge's two sides), their groups dense ids. Small universes keep the
    // windows crowded, so groups spill into each other's windows and wrap around the table's end.
    std::mt19937_64 rng(20261207);
    const auto churn = [&](auto& m, int group_shift, uint64_t groups) {
      std::map<uint64_t, uint32_t> ref;
      uint64_t erased = 0;
      for (int op = 0; op < 100000; ++op) {
        const uint64_t r = rng();
        const uint64_t group = r % groups, size = uint64_t(1) << group_shift;
        const uint64_t member = (r >> 40) % 4 == 0 ? (r >> 44) % size : (r >> 44) % std::min<uint64_t>(size, 3);
        const uint64_t key = (group << group_shift) + member;
        const int what = int((r >> 8) % 8);
        if (what < 4) {
          m.set(key, uint32_t(r >> 20));
          ref[key] = uint32_t(r >> 20);
        } else if (what < 7) {
          const bool had = ref.erase(key) == 1;
          CHECK(m.erase(key) == had);
          erased += had;
        } else {
          const auto it = ref.find(key);
          CHECK(m.get(key, 0xdeadu) == (it != ref.end() ? it->second : 0xdeadu));
        }
        REQUIRE(m.size() == ref.size());
        if (op % 997 == 0) check_equal(m, ref);
      }
      check_equal(m, ref);
      CHECK(erased > 5000);
      for (const auto& [k, v] : ref) CHECK(m.erase(k));
      CHECK(m.size() == 0);
    };
    for (uint64_t groups : {5ull, 17ull, 300ull, 20000ull}) {
      CAPTURE(groups);
      GroupedFlatMap<4, 2> patches(4);
      churn(patches, 4, groups);
      GroupedFlatMap<1, 1> sides(4);
      churn(sides, 1, groups);
    }
  }

  TEST_CASE("a grouped map keeps a group's first keys in consecutive slots of one window") {
    // A voxel's patches 0, 1, 2 in an empty table: three slots in a row from a window start (the
    // window's four slots are one cache line's worth), so a prefetch of patch 0 brings the others.
    GroupedFlatMap<4, 2> m(1000);
    for (uint32_t p = 0; p < 3; ++p) m.set(uint64_t(77) * 16 + p, p);
    // for_each walks the table in slot order: the keys come out in patch order.
    std::vector<uint64_t> order;
    m.for_each([&](uint64_t k, uint32_t) { order.push_back(k); });
    CHECK(order == std::vector<uint64_t>{77 * 16, 77 * 16 + 1, 77 * 16 + 2});
    m.prefetch(uint64_t(77) * 16);  // a hint only: changes nothing
    CHECK(m.get(uint64_t(77) * 16 + 2) == 2u);
  }

  TEST_CASE("every erase order of a full colliding cluster keeps the rest reachable") {
    // Keys sharing few home slots in a 16-slot table: a single cluster crossing the table's end.
    FlatMap probe(1);
    REQUIRE(probe.capacity() == 16);
    std::vector<uint64_t> keys;
    for (uint64_t k = 0; keys.size() < 12; ++k) keys.push_back(k * 7919);
    std::mt19937_64 rng(5);
    for (int round = 0; round < 2000; ++round) {
      FlatMap m(1);
      std::map<uint64_t, uint32_t> ref;
      for (size_t i = 0; i < keys.size(); ++i) {
        m.set(keys[i], uint32_t(i));
        ref[keys[i]] = uint32_t(i);
      }
      REQUIRE(m.capacity() == 16);
      std::vector<uint64_t> order = keys;
      for (size_t i = order.size(); i > 1; --i) std::swap(order[i - 1], order[rng() % i]);
      for (uint64_t k : order) {
        CHECK(m.erase(k));
        ref.erase(k);
        for (const auto& [kk, v] : ref) REQUIRE(m.get(kk) == v);
        // Re-insert sometimes to mix inserts into a shifted cluster.
        if (rng() % 4 == 0 && !ref.empty()) {
          const uint64_t back = ref.begin()->first;
          m.erase(back);
          m.set(back, 77);
          ref[back] = 77;
        }
      }
      check_equal(m, ref);
    }
  }

  TEST_CASE("growth keeps every entry and the load factor bounded") {
    FlatMap m;
    std::map<uint64_t, uint32_t> ref;
    uint64_t last_capacity = m.capacity();
    int growths = 0;
    for (uint64_t i = 0; i < 300000; ++i) {
      const uint64_t key = i * 3 + (i & 1);  // dense lattice-like ids
      m.set(key, uint32_t(i));
      ref[key] = uint32_t(i);
      if (m.capacity() != last_capacity) {
        CHECK(m.capacity() == 2 * last_capacity);
        last_capacity = m.capacity();
        ++growths;
      }
    }
    CHECK(growths >= 14);
    check_equal(m, ref);
    CHECK(m.memory_bytes() >= m.capacity() * 12);

    // reserve() up front: no growth afterwards, capacity a power of two.
    FlatMap r(100000);
    const uint64_t cap = r.capacity();
    CHECK((cap & (cap - 1)) == 0);
    for (uint64_t i = 0; i < 100000; ++i) r.set(i, uint32_t(i));
    CHECK(r.capacity() == cap);
    CHECK(r.size() == 100000);
    r.reserve(10);  // never shrinks
    CHECK(r.capacity() == cap);
    CHECK(r.get(99999) == 99999u);
  }

  TEST_CASE("for_each visits exactly the live entries after erases, and is deterministic") {
    auto build = [](FlatMap& m) {
      for (uint64_t i = 0; i < 5000; ++i) m.set(i * 11, uint32_t(i));
      for (uint64_t i = 0; i < 5000; i += 3) m.erase(i * 11);
    };
    FlatMap a, b;
    build(a);
    build(b);
    std::vector<std::pair<uint64_t, uint32_t>> va, vb;
    a.for_each([&](uint64_t k, uint32_t v) { va.emplace_back(k, v); });
    b.for_each([&](uint64_t k, uint32_t v) { vb.emplace_back(k, v); });
    CHECK(va == vb);
    std::set<uint64_t> seen;
    for (const auto& [k, v] : va) {
      CHECK(seen.insert(k).second);
      CHECK(k % 11 == 0);
      CHECK((k / 11) % 3 != 0);
      CHECK(v == k / 11);
    }
    CHECK(seen.size() == a.size());
    CHECK(a.size() == 5000 - 1667);
  }
}
