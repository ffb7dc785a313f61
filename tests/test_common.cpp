// Building blocks: the cross-lane triple buffer, the fixed histogram, the fault log and
// the allocation guard the other tests rely on.
#include <algorithm>
#include <csignal>
#include <ctime>
#include <fcntl.h>
#include <filesystem>
#include <fstream>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>
#include <array>
#include <atomic>
#include <catch2/catch.hpp>
#include <cstdlib>
#include <random>
#include <thread>
#include <vector>

#include "alloc_guard.hpp"
#include "test_files.hpp"
#include "markcell/common/file_history.hpp"
#include "markcell/common/fixed_string.hpp"
#include "markcell/common/fixed_vector.hpp"
#include "markcell/control/marking.hpp"
#include "markcell/common/spsc_ring.hpp"
#include "markcell/common/triple_buffer.hpp"
#include "markcell/control/faults.hpp"
#include "markcell/control/histogram.hpp"

using namespace markcell;

TEST_CASE("the allocation guard sees operator new and malloc from any thread") {
  test::AllocationGuard guard;
  CHECK(guard.allocations() == 0);
  auto* p = new int(3);
  CHECK(guard.allocations() == 1);
  delete p;
  void* volatile m = std::malloc(64);  // volatile: the pair cannot be optimised away
  CHECK(guard.allocations() == 2);
  std::free(m);
  std::size_t before = guard.allocations();
  std::thread([] { std::vector<int> v(100); (void)v; }).join();  // the thread's state and the vector
  CHECK(guard.allocations() >= before + 2);
}

TEST_CASE("triple buffer: the reader sees the newest complete value, never a torn one") {
  struct Pair {
    std::uint64_t a = 0, b = 0;  // the writer always stores b = 2a + 1
  };
  TripleBuffer<Pair> buffer;
  CHECK_FALSE(buffer.update());
  buffer.write(Pair{1, 3});
  buffer.write(Pair{2, 5});
  REQUIRE(buffer.update());
  CHECK(buffer.read().a == 2);  // the older one was overwritten, not queued
  CHECK_FALSE(buffer.update());
  CHECK(buffer.read().a == 2);

  constexpr std::uint64_t kWrites = 200000;
  std::atomic<bool> done{false}, started{false}, go{false};
  std::thread writer([&] {
    started = true;
    while (!go.load()) std::this_thread::yield();
    for (std::uint64_t i = 3; i <= kWrites; ++i) {
      Pair& slot = buffer.write_slot();
      slot.a = i;
      slot.b = 2 * i + 1;
      buffer.publish();
    }
    done = true;
  });
  std::uint64_t last = 2, torn = 0, backwards = 0;
  while (!started.load()) std::this_thread::yield();  // the thread's own start-up allocates
  test::AllocationGuard guard;
  go = true;
  for (;;) {
    const bool finished = done.load();  // read before update(): the last publish is then visible
    if (!buffer.update()) {
      if (finished) break;
      continue;
    }
    const Pair& p = buffer.read();
    if (p.b != 2 * p.a + 1) ++torn;
    if (p.a < last) ++backwards;
    last = p.a;
  }
  const auto allocations = guard.allocations();
  writer.join();
  CHECK(torn == 0);
  CHECK(backwards == 0);
  CHECK(last == kWrites);
  CHECK(allocations == 0);
}

TEST_CASE("histogram percentiles bound the exact order statistics within one bucket") {
  std::mt19937_64 rng(42);
  std::lognormal_distribution<double> dist(10.0, 1.5);  // ns, wide spread
  control::Histogram h;
  std::vector<Nanos> values;
  for (int i = 0; i < 20000; ++i) {
    const auto v = static_cast<Nanos>(dist(rng));
    values.push_back(v);
    h.record(v);
  }
  std::sort(values.begin(), values.end());
  CHECK(h.count() == values.size());
  CHECK(h.min() == values.front());
  CHECK(h.max() == values.back());
  for (double p : {0.5, 0.9, 0.99, 0.999}) {
    const auto rank = static_cast<std::size_t>(std::ceil(p * static_cast<double>(values.size())));
    const Nanos exact = values[rank - 1];
    const Nanos estimate = h.percentile(p);
    INFO("p=" << p << " exact=" << exact << " estimate=" << estimate);
    CHECK(estimate >= exact);  // an upper bound...
    CHECK(static_cast<double>(estimate) <= static_cast<double>(exact) * (1.0 + 1.0 / 16) + 1);  // ...within a bucket
  }
  // Exact for small values, and the bucket edges are consistent.
  for (Nanos v : {0, 1, 15, 16, 17, 1000, 123456789}) {
    const int b = control::Histogram::bucket_of(v);
    CHECK(control::Histogram::bucket_upper(b) >= v);
    if (b > 0) CHECK(control::Histogram::bucket_upper(b - 1) < v);
  }
}

TEST_CASE("fault log keeps order, counts what it cannot hold, and does not allocate") {
  control::FaultLog log;
  control::Fault f;
  test::AllocationGuard guard;
  for (std::size_t i = 0; i < control::FaultLog::kCapacity + 5; ++i) {
    f.time = static_cast<Nanos>(i);
    f.code = control::FaultCode::kTaskOverrun;
    f.detail.format("fault %zu", i);
    log.push(f);
  }
  CHECK(guard.allocations() == 0);
  CHECK(log.recorded() == control::FaultLog::kCapacity);
  CHECK(log.dropped() == 5);
  control::Fault out;
  REQUIRE(log.pop(out));
  CHECK(out.time == 0);
  CHECK(out.detail.view() == "fault 0");
  std::size_t n = 1;
  while (log.pop(out)) ++n;
  CHECK(n == control::FaultLog::kCapacity);
  CHECK(out.time == static_cast<Nanos>(control::FaultLog::kCapacity - 1));
}

TEST_CASE("fixed strings truncate at capacity instead of allocating") {
  FixedString<8> s("0123456789");
  CHECK(s.view() == "01234567");
  const char* volatile tail = "abcdefgh";  // not a constant: the truncation happens at run time
  s.format("%d-%s", 42, tail);
  CHECK(s.view() == "42-abcde");
}

// The reference is std::vector: the same pushes give the same elements, up to the
// capacity; past it nothing is written and the overflow is remembered until clear().
TEST_CASE("fixed vectors hold what fits, refuse the rest with a flag, and never allocate") {
  FixedVector<int, 4> v;
  std::array<bool, 6> taken{};
  std::size_t allocations = 0;
  {
    test::AllocationGuard guard;
    for (int i = 0; i < 6; ++i) taken[static_cast<std::size_t>(i)] = v.push_back(10 * i);
    allocations = guard.allocations();
  }
  CHECK(allocations == 0);
  std::vector<int> reference;
  for (int i = 0; i < 6; ++i)
    if (taken[static_cast<std::size_t>(i)]) reference.push_back(10 * i);
  CHECK(v.size() == 4);
  CHECK(v.full());
  CHECK(v.overflowed());
  CHECK(std::vector<int>(v.begin(), v.end()) == std::vector<int>{0, 10, 20, 30});
  CHECK(std::vector<int>(v.begin(), v.end()) == reference);
  CHECK(v.emplace_back() == nullptr);
  v.truncate(2);
  CHECK(v.ssize() == 2);
  CHECK(v.back() == 10);
  CHECK(v.overflowed());  // truncating does not forget a refusal
  v.clear();
  CHECK(v.empty());
  CHECK_FALSE(v.overflowed());
  int* slot = v.emplace_back();
  REQUIRE(slot != nullptr);
  CHECK(*slot == 0);  // value-initialised, whatever was there before
}

// One tally for the journal line, the replay's progress and the report: a pulse cut
// short counts as sprayed and as skipped, as each of them counted it before.
TEST_CASE("a panel result's tally counts sprayed and skipped defects independently") {
  control::PanelResult r;
  const auto add = [&](bool sprayed, control::SkipReason skipped) {
    control::DefectResult* d = r.defects.emplace_back();
    REQUIRE(d != nullptr);
    d->sprayed = sprayed;
    d->skipped = skipped;
  };
  add(true, control::SkipReason::kNone);
  add(true, control::SkipReason::kCutShort);
  add(false, control::SkipReason::kPlanned);
  add(false, control::SkipReason::kNone);  // still open
  const auto t = r.tally();
  CHECK(t.sprayed == 2);
  CHECK(t.skipped == 2);
}

TEST_CASE("spsc ring: every value pushed is popped once, in order, or counted as dropped, with no heap use") {
  struct Item {
    std::uint64_t n = 0;
    std::array<std::uint64_t, 7> copy{};  // the same number 7 times: a torn read shows
  };
  static SpscRing<Item, 64> ring;  // (static: 4 KiB off the test's stack)
  constexpr std::uint64_t kCount = 200'000;
  std::atomic<bool> done{false};
  std::uint64_t pushed = 0;
  std::size_t allocations = 0;
  std::thread producer([&] {
    test::AllocationGuard guard;  // from here, in both threads
    for (std::uint64_t i = 1; i <= kCount; ++i) {
      Item it;
      it.n = i;
      it.copy.fill(i);
      if (ring.push(it)) ++pushed;
    }
    allocations = guard.allocations();
    done.store(true, std::memory_order_release);
  });
  std::uint64_t popped = 0, last = 0;
  bool ordered = true, whole = true;
  Item got;
  for (;;) {
    const bool finished = done.load(std::memory_order_acquire);
    while (ring.pop(got)) {
      ++popped;
      ordered = ordered && got.n > last;
      last = got.n;
      for (const auto c : got.copy) whole = whole && c == got.n;
    }
    if (finished) break;
  }
  producer.join();
  CHECK(ordered);
  CHECK(whole);
  CHECK(popped == pushed);
  CHECK(pushed + ring.dropped() == kCount);
  CHECK(allocations == 0);
  // A full ring refuses the next value and counts it; a pop makes room again.
  SpscRing<int, 4> small;
  for (int i = 0; i < 4; ++i) CHECK(small.push(i));
  CHECK_FALSE(small.push(4));
  CHECK(small.dropped() == 1);
  int v = -1;
  CHECK(small.pop(v));
  CHECK(v == 0);
  CHECK(small.push(5));
}

// --- State files: atomic replacement with a dated, bounded history ---------------------

namespace {

std::string read_all(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}
void write_text(const std::string& file, const std::string& text) {
  std::ofstream(file, std::ios::binary) << text;
}
// Sets a file's modification time (seconds since the epoch, UTC).
void set_mtime(const std::filesystem::path& p, std::time_t t) {
  const struct timespec times[2] = {{t, 0}, {t, 0}};
  REQUIRE(::utimensat(AT_FDCWD, p.c_str(), times, 0) == 0);
}

}  // namespace

TEST_CASE("UTC times: ISO 8601 and the file-name form, against known dates") {
  CHECK(markcell::utc_iso8601(0) == "1970-01-01T00:00:00Z");
  CHECK(markcell::utc_iso8601(1700000000) == "2023-11-14T22:13:20Z");
  CHECK(markcell::utc_compact(1700000000) == "20231114T221320Z");
  CHECK(markcell::utc_compact(951782400) == "20000229T000000Z");  // a leap day
}

TEST_CASE("UTC to the millisecond: against Hinnant's civil-from-days over 2000 random instants, rounded down") {
  // The reference: Howard Hinnant's civil_from_days (chrono's own algorithm), written
  // out here, not gmtime as the code under test uses.
  const auto reference = [](std::int64_t ns) {
    std::int64_t s = ns / 1'000'000'000, r = ns % 1'000'000'000;
    if (r < 0) {
      --s;
      r += 1'000'000'000;
    }
    std::int64_t days = s / 86400, sec = s % 86400;
    if (sec < 0) {
      --days;
      sec += 86400;
    }
    const std::int64_t z = days + 719468, era = (z >= 0 ? z : z - 146096) / 146097, doe = z - era * 146097;
    const std::int64_t yoe = (doe - doe / 1460 + doe / 36524 - doe / 146096) / 365, doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    const std::int64_t mp = (5 * doy + 2) / 153, d = doy - (153 * mp + 2) / 5 + 1, m = mp < 10 ? mp + 3 : mp - 9;
    const std::int64_t y = yoe + era * 400 + (m <= 2 ? 1 : 0);
    char text[40];
    std::snprintf(text, sizeof text, "%04lld-%02lld-%02lldT%02lld:%02lld:%02lld.%03lldZ", static_cast<long long>(y),
                  static_cast<long long>(m), static_cast<long long>(d), static_cast<long long>(sec / 3600),
                  static_cast<long long>(sec / 60 % 60), static_cast<long long>(sec % 60), static_cast<long long>(r / 1'000'000));
    return std::string(text);
  };
  std::mt19937_64 rng(20261207);
  // 1900 to 2200: every century rule of the calendar, and the years before the epoch.
  std::uniform_int_distribution<std::int64_t> instant(-2'208'988'800LL * 1'000'000'000, 7'258'118'400LL * 1'000'000'000);
  for (int i = 0; i < 2000; ++i) {
    const std::int64_t ns = instant(rng);
    INFO(ns);
    REQUIRE(markcell::utc_iso8601_ms(ns) == reference(ns));
  }
  CHECK(markcell::utc_iso8601_ms(0) == "1970-01-01T00:00:00.000Z");
  CHECK(markcell::utc_iso8601_ms(1'700'000'000'999'999'999) == "2023-11-14T22:13:20.999Z");  // rounded down
  CHECK(markcell::utc_iso8601_ms(951'782'400'123'000'000) == "2000-02-29T00:00:00.123Z");
  CHECK(markcell::utc_iso8601_ms(-1) == "1969-12-31T23:59:59.999Z");
}

TEST_CASE("a state file is replaced atomically, its previous versions kept by date and bounded") {
  markcell::test::TempDir dir;
  const auto path = dir.path() / "base.yaml";
  const auto history = dir.path() / "history";
  const auto write = [](const std::string& text) {
    return [text](const std::string& temporary) {
      // The writer is handed a file beside the target with the same extension.
      CHECK(std::filesystem::path(temporary).extension() == ".yaml");
      write_text(temporary, text);
    };
  };
  // The first version: nothing to keep.
  auto r = markcell::replace_file_keeping_history(path, write("v1"));
  CHECK(r.kept.empty());
  CHECK(read_all(path) == "v1");
  CHECK_FALSE(std::filesystem::exists(history));

  // The second: the first kept under its own date, byte for byte.
  set_mtime(path, 1700000000);
  r = markcell::replace_file_keeping_history(path, write("v2"));
  CHECK(r.kept == history / "base.20231114T221320Z.yaml");
  CHECK(read_all(r.kept) == "v1");
  CHECK(read_all(path) == "v2");
  // Two versions from the same second both kept, the later one after.
  set_mtime(path, 1700000000);
  r = markcell::replace_file_keeping_history(path, write("v3"));
  CHECK(r.kept == history / "base.20231114T221320Z-02.yaml");
  CHECK(read_all(r.kept) == "v2");
  const auto listed = markcell::file_history(path);
  REQUIRE(listed.size() == 2);
  CHECK(listed[0].filename() == "base.20231114T221320Z-02.yaml");  // newest first
  // Only this file's versions are its history: another file's and strays are not.
  write_text((history / "stereo.20231114T221320Z.yaml").string(), "other");
  write_text((history / "base.notadate.yaml").string(), "stray");
  CHECK(markcell::file_history(path).size() == 2);

  // A writer that fails leaves the file, the history and no temporary file behind.
  CHECK_THROWS_WITH(markcell::replace_file_keeping_history(path,
                                                           [](const std::string& temporary) {
                                                             write_text(temporary, "half");
                                                             throw std::runtime_error("disk full");
                                                           }),
                    "disk full");
  CHECK(read_all(path) == "v3");
  CHECK(markcell::file_history(path).size() == 2);
  for (const auto& e : std::filesystem::directory_iterator(dir.path())) CHECK(e.path().filename().string()[0] != '.');

  // Bounded: after 12 more versions a day apart, the newest kHistoryKept remain.
  for (int i = 0; i < 12; ++i) {
    set_mtime(path, 1700000000 + 86400 * (i + 1));
    markcell::replace_file_keeping_history(path, write("v" + std::to_string(4 + i)));
  }
  const auto kept = markcell::file_history(path);
  REQUIRE(kept.size() == markcell::kHistoryKept);
  CHECK(kept.front().filename() == "base." + markcell::utc_compact(1700000000 + 86400 * 12) + ".yaml");
  CHECK(read_all(kept.front()) == "v14");
  CHECK(read_all(path) == "v15");
  CHECK(std::filesystem::exists(history / "stereo.20231114T221320Z.yaml"));  // not base's: untouched

  // No folder: said with the path.
  CHECK_THROWS_WITH(markcell::replace_file_keeping_history(dir.path() / "none" / "x.yaml", write("x")),
                    (dir.path() / "none" / "x.yaml").string() + ": its folder " + (dir.path() / "none").string() +
                        " does not exist");
}

TEST_CASE("a crash while a state file is written leaves the previous version whole") {
  markcell::test::TempDir dir;
  const auto path = dir.path() / "stereo.yaml";
  write_text(path.string(), "the calibration in use");
  // A child killed (SIGKILL: no cleanup) half way through writing the new version.
  const pid_t child = ::fork();
  REQUIRE(child >= 0);
  if (child == 0) {
    markcell::replace_file_keeping_history(path, [](const std::string& temporary) {
      write_text(temporary, "half of the new");
      ::raise(SIGKILL);
    });
    ::_exit(0);
  }
  int status = 0;
  REQUIRE(::waitpid(child, &status, 0) == child);
  REQUIRE(WIFSIGNALED(status));
  CHECK(WTERMSIG(status) == SIGKILL);
  CHECK(read_all(path) == "the calibration in use");
  // The next write takes over the dead one's temporary file.
  markcell::replace_file_keeping_history(path, [](const std::string& t) { write_text(t, "new"); });
  CHECK(read_all(path) == "new");
  REQUIRE(markcell::file_history(path).size() == 1);
  CHECK(read_all(markcell::file_history(path)[0]) == "the calibration in use");
}
