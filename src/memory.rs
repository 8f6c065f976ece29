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
    /// Nothing known about the machine: no limit.
    Unknown,
}

impl MemoryBudget {
    /// [`DEFAULT_SHARE`] of the cgroup limit, else of physical memory.
    pub fn default_for_machine() -> Self {
        let physical = physical_memory();
        let share = |b: u64| (b as f64 * DEFAULT_SHARE) as u64;
        match (cgroup_limit(), physical) {
            (Some(c), p) if p.is_none_or(|p| c < p) => Self { bytes: share(c), source: BudgetSource::Cgroup },
            (_, Some(p)) => Self { bytes: share(p), source: BudgetSource::Physical },
            _ => Self { bytes: u64::MAX, source: BudgetSource::Unknown },
        }
    }
}

impl fmt::Display for MemoryBudget {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let share = (DEFAULT_SHARE * 100.0) as u32;
        match self.source {
            BudgetSource::Given => write!(f, "{} (--memory-budget)", Bytes(self.bytes)),
            BudgetSource::Cgroup => write!(f, "{} ({share}% of the cgroup memory limit)", Bytes(self.bytes)),
            BudgetSource::Physical => write!(f, "{} ({share}% of physical memory)", Bytes(self.bytes)),
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

/// The cgroup memory limit of this process, when one is set (cgroup v2
/// `memory.max`, else v1 `memory.limit_in_bytes`).
pub fn cgroup_limit() -> Option<u64> {
    let v2 = std::fs::read_to_string("/proc/self/cgroup").ok().and_then(|text| {
        let path = text.lines().find_map(|l| l.strip_prefix("0::"))?.trim().to_string();
        std::fs::read_to_string(format!("/sys/fs/cgroup{path}/memory.max"))
            .or_else(|_| std::fs::read_to_string("/sys/fs/cgroup/memory.max"))
            .ok()
    });
    let text = v2.or_else(|| std::fs::read_to_string("/sys/fs/cgroup/memory/memory.limit_in_bytes").ok())?;
    // "max", or a huge number, means no limit.
    text.trim().parse::<u64>().ok().filter(|&b| b < 1 << 60)
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
    fn the_default_budget_is_a_share_of_the_machine() {
        let b = MemoryBudget::default_for_machine();
        if let Some(p) = physical_memory() {
            assert!(b.bytes <= p && b.bytes > 0, "{b}");
        }
        assert!(peak_resident().is_none_or(|r| r > 1 << 20));
    }
}
