//! Memory budgets: sizes as users write them (`512M`, `4G`), the default
//! budget from the machine's limits, and the peak resident memory a
//! process reached (what a budget bounds).
//!
//! A budget counts everything a command keeps resident: heap, mapped file
//! pages, buffers. What it cannot count (the program's code and libraries,
//! thread stacks, the allocator's slack) is bounded by [`UNCOUNTED`]: a
//! command run under budget B peaks below B + [`UNCOUNTED`], or says at
//! once that it cannot run within B.

use std::fmt;

/// Resident memory a budget does not count, at most: the binary and its
/// libraries, thread stacks, allocator slack (measured: a render of a
/// tiny archive peaks at ~12 MB).
pub const UNCOUNTED: u64 = 64 << 20;

/// The share of the machine's memory the default budget takes: three
/// quarters of the cgroup limit where one is set, else of physical RAM.
pub const DEFAULT_SHARE: f64 = 0.75;

/// The share of the address space left under `RLIMIT_AS` (`ulimit -v`)
/// the default budget takes. Smaller than [`DEFAULT_SHARE`] because the
/// limit counts what residency does not: a mapped file whole, and what
/// the allocators reserve ahead of use (measured: a Cornell box build
/// 290 MiB resident needs 550 MB of address space).
pub const ADDRESS_SPACE_SHARE: f64 = 0.5;

/// Address space held back under `RLIMIT_AS`, per worker thread, before
/// [`ADDRESS_SPACE_SHARE`] is taken: mimalloc maps each 32 MiB segment
/// (and each block larger than one) through a window one segment wider to
/// align it, so every thread allocating at once needs that much free.
pub const ALLOCATOR_WINDOW: u64 = 64 << 20;

/// A memory budget and where it came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryBudget {
    /// Bytes.
    pub bytes: u64,
    /// Who set it.
    pub source: BudgetSource,
}

/// Where a [`MemoryBudget`] came from (for messages).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BudgetSource {
    /// `--memory-budget`.
    Given,
    /// [`DEFAULT_SHARE`] of the cgroup memory limit.
    Cgroup,
    /// [`DEFAULT_SHARE`] of physical memory.
    Physical,
    /// [`ADDRESS_SPACE_SHARE`] of the address space `RLIMIT_AS` leaves.
    AddressSpace,
    /// Nothing known about the machine: no limit.
    Unknown,
}

impl MemoryBudget {
    /// The least of: [`DEFAULT_SHARE`] of physical memory, of the cgroup
    /// limit, and [`ADDRESS_SPACE_SHARE`] of the address space
    /// `RLIMIT_AS` leaves; a job any of these cannot hold is then refused
    /// (exit 6) instead of aborting in the allocator or being killed.
    pub fn default_for_machine() -> Self {
        let mut budget = Self { bytes: u64::MAX, source: BudgetSource::Unknown };
        let mut offer = |bytes: u64, source| {
            if bytes < budget.bytes {
                budget = Self { bytes, source };
            }
        };
        let share = |b: u64, s: f64| (b as f64 * s) as u64;
        if let Some(p) = physical_memory() {
            offer(share(p, DEFAULT_SHARE), BudgetSource::Physical);
        }
        if let Some(c) = cgroup_limit() {
            offer(share(c, DEFAULT_SHARE), BudgetSource::Cgroup);
        }
        if let Some(a) = address_space_limit() {
            let windows = ALLOCATOR_WINDOW * rayon::current_num_threads().max(1) as u64;
            let left = a.saturating_sub(address_space_in_use().unwrap_or(0)).saturating_sub(windows);
            offer(share(left, ADDRESS_SPACE_SHARE), BudgetSource::AddressSpace);
        }
        budget
    }
}

impl fmt::Display for MemoryBudget {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let share = (DEFAULT_SHARE * 100.0) as u32;
        match self.source {
            BudgetSource::Given => write!(f, "{} (--memory-budget)", Bytes(self.bytes)),
            BudgetSource::Cgroup => write!(f, "{} ({share}% of the cgroup memory limit)", Bytes(self.bytes)),
            BudgetSource::Physical => write!(f, "{} ({share}% of physical memory)", Bytes(self.bytes)),
            BudgetSource::AddressSpace => write!(
                f,
                "{} ({}% of the address space left under `ulimit -v`)",
                Bytes(self.bytes),
                (ADDRESS_SPACE_SHARE * 100.0) as u32
            ),
            BudgetSource::Unknown => write!(f, "unlimited (the machine's memory is unknown)"),
        }
    }
}

/// A byte count shown in binary units (`48.0 MiB`).
#[derive(Clone, Copy, Debug)]
pub struct Bytes(pub u64);

impl fmt::Display for Bytes {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let units = ["B", "KiB", "MiB", "GiB", "TiB", "PiB"];
        let mut x = self.0 as f64;
        let mut u = 0;
        while x >= 1024.0 && u + 1 < units.len() {
            x /= 1024.0;
            u += 1;
        }
        // Two decimals from GiB on: peaks near a budget of a few GiB
        // must show whether they are over it.
        match u {
            0 => write!(f, "{} B", self.0),
            1 | 2 => write!(f, "{x:.1} {}", units[u]),
            _ => write!(f, "{x:.2} {}", units[u]),
        }
    }
}

/// Parses a size: a number (decimals allowed) and an optional binary
/// multiple `K`, `M`, `G` or `T` (powers of 1024; `Ki`, `KiB` and `KB`
/// mean the same), e.g. `512M`, `4G`, `1.5GiB`, `65536`.
pub fn parse_size(text: &str) -> Result<u64, String> {
    let t = text.trim();
    let split = t.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let value: f64 = number
        .parse()
        .map_err(|_| format!("`{text}` is not a size: write a number with an optional K, M, G or T (e.g. 512M, 4G)"))?;
    let unit = unit.trim();
    let unit = unit.strip_suffix(['B', 'b']).unwrap_or(unit);
    let unit = unit.strip_suffix(['i', 'I']).unwrap_or(unit);
    let scale: u64 = match unit.to_ascii_uppercase().as_str() {
        "" => 1,
        "K" => 1 << 10,
        "M" => 1 << 20,
        "G" => 1 << 30,
        "T" => 1 << 40,
        _ => return Err(format!("`{text}`: unknown unit `{unit}` (use K, M, G or T: powers of 1024)")),
    };
    let bytes = value * scale as f64;
    if !(bytes.is_finite() && bytes >= 1.0 && bytes < u64::MAX as f64) {
        return Err(format!("`{text}` is not a usable size"));
    }
    Ok(bytes as u64)
}

/// The memory limit of this process's cgroup, when one is set: the least
/// over its cgroup and every ancestor (a limit set on a parent, as a job
/// scheduler's slice or a container's, binds the child too), cgroup v2
/// `memory.max` or v1 `memory.limit_in_bytes`.
pub fn cgroup_limit() -> Option<u64> {
    let membership = std::fs::read_to_string("/proc/self/cgroup").ok()?;
    cgroup_limit_in(std::path::Path::new("/sys/fs/cgroup"), &membership)
}

/// [`cgroup_limit`] for a cgroup file system mounted at `root` and a
/// `/proc/self/cgroup` text.
fn cgroup_limit_in(root: &std::path::Path, membership: &str) -> Option<u64> {
    let mut least: Option<u64> = None;
    for line in membership.lines() {
        let mut fields = line.splitn(3, ':');
        let (Some(id), Some(controllers), Some(path)) = (fields.next(), fields.next(), fields.next()) else {
            continue;
        };
        let (dir, file) = if id == "0" && controllers.is_empty() {
            (root.to_path_buf(), "memory.max")
        } else if controllers.split(',').any(|c| c == "memory") {
            (root.join("memory"), "memory.limit_in_bytes")
        } else {
            continue;
        };
        // The cgroup, then each ancestor up to the mount's root (which is
        // also where a container sees its own cgroup).
        let mut at = Some(std::path::Path::new(path.trim().trim_start_matches('/')));
        while let Some(p) = at {
            let limit = std::fs::read_to_string(dir.join(p).join(file)).ok();
            // "max", or a huge number, means no limit.
            if let Some(b) = limit.and_then(|t| t.trim().parse::<u64>().ok()).filter(|&b| b < 1 << 60) {
                least = Some(least.map_or(b, |l| l.min(b)));
            }
            at = p.parent();
        }
    }
    least
}

/// The address-space limit of this process (`RLIMIT_AS`, which
/// `ulimit -v` sets), when one is set.
pub fn address_space_limit() -> Option<u64> {
    let mut limit = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
    // SAFETY: getrlimit writes one `rlimit` this frame owns.
    let read = unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut limit) } == 0;
    (read && limit.rlim_cur != libc::RLIM_INFINITY).then_some(limit.rlim_cur)
}

/// The address space this process uses now, on Linux: every mapping of
/// `/proc/self/maps` but the anonymous inaccessible ones, which are what
/// the allocators reserved ahead of use (mimalloc takes 128 MiB where it
/// may not take its 1 GiB arena) and will fill before they map more.
pub fn address_space_in_use() -> Option<u64> {
    let maps = std::fs::read_to_string("/proc/self/maps").ok()?;
    Some(maps.lines().map(mapping_in_use).sum())
}

/// The bytes one line of `/proc/self/maps` uses of the address space: its
/// length, or 0 for an anonymous `---p` reservation.
fn mapping_in_use(line: &str) -> u64 {
    let mut fields = line.split_whitespace();
    let (Some(range), Some(perms)) = (fields.next(), fields.next()) else { return 0 };
    let path = fields.nth(3);
    if perms == "---p" && path.is_none() {
        return 0;
    }
    let Some((start, end)) = range.split_once('-') else { return 0 };
    match (u64::from_str_radix(start, 16), u64::from_str_radix(end, 16)) {
        (Ok(s), Ok(e)) => e.saturating_sub(s),
        _ => 0,
    }
}

/// Under an address-space limit, keeps the C allocator (glibc's, which
/// zstd and the system libraries use) to one arena: each further arena
/// reserves 64 MiB of address space per thread that the budget cannot
/// count. Does nothing without a limit.
pub fn fit_allocators_to_address_space() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    if address_space_limit().is_some() {
        // SAFETY: mallopt sets an allocator parameter; called before the
        // worker threads start, and harmless after.
        unsafe { libc::mallopt(libc::M_ARENA_MAX, 1) };
    }
}

/// Physical memory (`MemTotal` of `/proc/meminfo`).
pub fn physical_memory() -> Option<u64> {
    proc_kib("/proc/meminfo", "MemTotal:")
}

/// The peak resident set size of this process so far (`VmHWM` of
/// `/proc/self/status`), on Linux.
pub fn peak_resident() -> Option<u64> {
    proc_kib("/proc/self/status", "VmHWM:")
}

/// Starts [`peak_resident`] afresh from what is resident now (writes 5 to
/// `/proc/self/clear_refs`, on Linux; elsewhere, or where that is not
/// allowed, the peak stays the process's): so that one process running
/// two stages (`demo`: a build, then a render) reports each stage's peak.
/// Returns whether it did.
pub fn reset_peak_resident() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// The resident set size of this process now (`VmRSS` of
/// `/proc/self/status`), on Linux: what a plan made mid-run starts from.
pub fn resident_now() -> Option<u64> {
    proc_kib("/proc/self/status", "VmRSS:")
}

/// A `key: N kB` line of a `/proc` file, in bytes.
fn proc_kib(file: &str, key: &str) -> Option<u64> {
    let text = std::fs::read_to_string(file).ok()?;
    let line = text.lines().find(|l| l.starts_with(key))?;
    let kib: u64 = line[key.len()..].trim().trim_end_matches("kB").trim().parse().ok()?;
    Some(kib * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_in_binary_units() {
        assert_eq!(parse_size("512M"), Ok(512 << 20));
        assert_eq!(parse_size("4G"), Ok(4 << 30));
        assert_eq!(parse_size("1.5GiB"), Ok(3 << 29));
        assert_eq!(parse_size(" 48 MB "), Ok(48 << 20));
        assert_eq!(parse_size("65536"), Ok(65536));
        assert_eq!(parse_size("2t"), Ok(2 << 40));
        for bad in ["", "M", "12Q", "-1G", "0", "1e3", "nan"] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn bytes_print_in_binary_units() {
        assert_eq!(Bytes(48 << 20).to_string(), "48.0 MiB");
        assert_eq!(Bytes(1000).to_string(), "1000 B");
        assert_eq!(Bytes(3 << 29).to_string(), "1.50 GiB");
    }

    #[test]
    fn a_cgroup_limit_is_the_least_over_the_cgroup_and_its_ancestors() {
        let root = tempfile::tempdir().unwrap();
        let write = |rel: &str, text: &str| {
            let path = root.path().join(rel);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(path, text).unwrap();
        };
        // v1: a limit on the parent binds a child with none of its own.
        write("memory/memory.limit_in_bytes", "9223372036854771712\n");
        write("memory/jobs/memory.limit_in_bytes", "1073741824\n");
        write("memory/jobs/42/memory.limit_in_bytes", "9223372036854771712\n");
        let v1 = "4:memory:/jobs/42\n3:cpuset:/\n";
        assert_eq!(cgroup_limit_in(root.path(), v1), Some(1 << 30));
        // v2: the child's own limit, smaller than the parent's.
        write("slice/memory.max", "2147483648\n");
        write("slice/job/memory.max", "536870912\n");
        assert_eq!(cgroup_limit_in(root.path(), "0::/slice/job\n"), Some(512 << 20));
        // No limit anywhere, or no memory controller.
        write("free/memory.max", "max\n");
        assert_eq!(cgroup_limit_in(root.path(), "0::/free\n"), None);
        assert_eq!(cgroup_limit_in(root.path(), "3:cpuset:/jobs/42\n"), None);
    }

    #[test]
    fn reservations_do_not_count_as_address_space_in_use() {
        assert_eq!(mapping_in_use("7f00-7f10 rw-p 00000000 00:00 0"), 0x10);
        assert_eq!(mapping_in_use("434ad400000-434b5400000 ---p 00000000 00:00 0 "), 0);
        assert_eq!(mapping_in_use("5600-5700 r-xp 00000000 08:01 1234 /usr/bin/x"), 0x100);
        assert_eq!(mapping_in_use("5600-5700 ---p 00000000 08:01 1234 /usr/lib/libc.so.6"), 0x100);
        assert_eq!(mapping_in_use("garbage"), 0);
        assert!(address_space_in_use().is_none_or(|b| b > 1 << 20));
    }

    #[test]
    fn the_default_budget_is_a_share_of_the_machine() {
        let b = MemoryBudget::default_for_machine();
        if let Some(p) = physical_memory() {
            assert!(b.bytes <= p && b.bytes > 0, "{b}");
        }
        assert!(peak_resident().is_none_or(|r| r > 1 << 20));
    }
}
