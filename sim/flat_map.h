// A flat open-addressing hash map from 64-bit keys to 32-bit values.
//
// Why not std::unordered_map: one allocation for the whole table (no node per entry), cache
// friendly probing, and nothing in sim/ may depend on unordered iteration order anyway — this map
// has no iteration at all except `for_each`, whose order depends only on the sequence of inserts
// and erases (deterministic for a deterministic program). Erase uses backward-shift deletion, so
// there are no tombstones and lookups stay short after many cuts.
//
// Grouped keys (GroupedFlatMap): keys that are read together (the patches of one voxel, the two
// half-edges of one lattice edge) share their home's cache line: the hash mixes key >> GroupShift and
// adds the low GroupShift bits to the window it picks, so a voxel's patches 0, 1, 2 sit in
// consecutive slots and one miss serves all of them (the surface's maps outgrow the caches: a miss
// per key was a third of a cut step's time). Linear probing and backward-shift deletion hold for
// any home function of the key, so gets, sets and erases are those of FlatMap; only for_each's
// order differs.
#pragma once

#include "sim/random.h"

#include <cstdint>
#include <vector>

namespace dvx {

// GroupShift: the low key bits a group shares its window by (0: every key hashed on its own);
// WindowShift: the window's slots as a power of two (a group's first keys land in it, later ones
// spill on).
template <int GroupShift, int WindowShift>
class GroupedFlatMap {
 public:
  static constexpr uint64_t kEmpty = ~uint64_t(0);  // reserved: not a valid key

  GroupedFlatMap() { reserve(16); }
  explicit GroupedFlatMap(uint32_t expected) { reserve(expected); }

  // Value of `key`, or `fallback` when absent.
  uint32_t get(uint64_t key, uint32_t fallback = ~0u) const {
    uint64_t i = slot_of(key);
    while (true) {
      const Entry& e = entries_[i];
      if (e.key == key) return e.value;
      if (e.key == kEmpty) return fallback;
      i = (i + 1) & mask_;
    }
  }
  // Starts loading the cache line of `key`'s home slot (a later get, set or erase of it, or of a key
  // of its group, finds it there).
  void prefetch(uint64_t key) const { __builtin_prefetch(&entries_[slot_of(key)]); }

  bool contains(uint64_t key) const {
    uint64_t i = slot_of(key);
    while (entries_[i].key != kEmpty) {
      if (entries_[i].key == key) return true;
      i = (i + 1) & mask_;
    }
    return false;
  }

  // Inserts or overwrites.
  void set(uint64_t key, uint32_t value) {
    if ((size_ + 1) * 4 > capacity() * 3) grow();
    uint64_t i = slot_of(key);
    while (true) {
      Entry& e = entries_[i];
      if (e.key == key) {
        e.value = value;
        return;
      }
      if (e.key == kEmpty) {
        e.key = key;
        e.value = value;
        ++size_;
        return;
      }
      i = (i + 1) & mask_;
    }
  }

  // Removes `key`; returns false when it was absent.
  bool erase(uint64_t key) {
    uint64_t i = slot_of(key);
    while (true) {
      if (entries_[i].key == kEmpty) return false;
      if (entries_[i].key == key) break;
      i = (i + 1) & mask_;
    }
    // Backward-shift: move later entries of the probe chain into the hole.
    uint64_t hole = i;
    uint64_t j = (i + 1) & mask_;
    while (entries_[j].key != kEmpty) {
      const uint64_t home = slot_of(entries_[j].key);
      // Entry j may move to the hole when its home is not in (hole, j] cyclically.
      const bool between = hole <= j ? (home > hole && home <= j) : (home > hole || home <= j);
      if (!between) {
        entries_[hole] = entries_[j];
        hole = j;
      }
      j = (j + 1) & mask_;
    }
    entries_[hole].key = kEmpty;
    --size_;
    return true;
  }

  uint32_t size() const { return size_; }
  uint64_t capacity() const { return mask_ + 1; }
  uint64_t memory_bytes() const { return entries_.capacity() * sizeof(Entry); }
  void clear() {
    for (Entry& e : entries_) e.key = kEmpty;
    size_ = 0;
  }

  void reserve(uint32_t expected) {
    uint64_t want = 16;
    while (want * 3 < uint64_t(expected) * 4 + 4) want *= 2;
    if (want > capacity() || entries_.empty()) rehash(want);
  }

  // Calls f(key, value) for every entry (table order).
  template <typename F>
  void for_each(F&& f) const {
    for (const Entry& e : entries_) {
      if (e.key != kEmpty) f(e.key, e.value);
    }
  }

 private:
  struct Entry {
    uint64_t key;
    uint32_t value;
  };

  // splitmix64 finaliser: good spread for lattice ids, which are dense integers. Grouped: the group's
  // mixed id picks a window, the key's low bits its place from the window's start.
  uint64_t slot_of(uint64_t key) const {
    const uint64_t g = mix64(key >> GroupShift);
    return ((g << WindowShift) + (key & ((uint64_t(1) << GroupShift) - 1))) & mask_;
  }

  void grow() { rehash(capacity() * 2); }

  void rehash(uint64_t new_capacity) {
    std::vector<Entry> old;
    old.swap(entries_);
    entries_.assign(new_capacity, Entry{kEmpty, 0});
    mask_ = new_capacity - 1;
    size_ = 0;
    for (const Entry& e : old) {
      if (e.key != kEmpty) set(e.key, e.value);
    }
  }

  std::vector<Entry> entries_;
  uint64_t mask_ = 0;
  uint32_t size_ = 0;
};

// Every key on its own.
using FlatMap = GroupedFlatMap<0, 0>;

}  // namespace dvx
