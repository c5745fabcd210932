//! A compact table of strings indexed by typed id: one text buffer and the
//! end offset of each entry, for the names a simulation needs after the
//! equation system is gone (a 10^5-section ladder's 5·10^5 variable names
//! are 5 MB here, against about 40 MB as separate `String`s).

use super::entity::EntityId;
use std::marker::PhantomData;

/// Strings keyed by `K`, in one buffer.
#[derive(Clone, Debug)]
pub struct NameTable<K> {
    text: String,
    /// `ends[k]` is where entry `k` ends in `text`; it starts where entry
    /// `k - 1` ends.
    ends: Vec<usize>,
    key: PhantomData<fn(K)>,
}

impl<K> Default for NameTable<K> {
    fn default() -> Self {
        NameTable {
            text: String::new(),
            ends: Vec::new(),
            key: PhantomData,
        }
    }
}

impl<K: EntityId> NameTable<K> {
    /// The table of `names`, in order: the first is key 0.
    pub fn of<'a>(names: impl IntoIterator<Item = &'a str>) -> Self {
        let mut t = NameTable::default();
        for n in names {
            t.push(n);
        }
        t
    }

    /// Room for `n` more names of `bytes` bytes in all.
    pub fn reserve(&mut self, n: usize, bytes: usize) {
        self.ends.reserve(n);
        self.text.reserve(bytes);
    }

    /// Append `name` under the next key.
    pub fn push(&mut self, name: &str) -> K {
        let k = K::new(self.ends.len());
        self.text.push_str(name);
        self.ends.push(self.text.len());
        k
    }

    /// The name of `k`; empty for a key the table does not have.
    pub fn get(&self, k: K) -> &str {
        let i = k.index();
        match self.ends.get(i) {
            Some(&end) => {
                let start = if i == 0 { 0 } else { self.ends[i - 1] };
                &self.text[start..end]
            }
            None => "",
        }
    }

    pub fn len(&self) -> usize {
        self.ends.len()
    }

    pub fn is_empty(&self) -> bool {
        self.ends.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ir::{EntityId, VarId};

    #[test]
    fn names_come_back_by_key() {
        let t: NameTable<VarId> = NameTable::of(["u_R1", "", "der(u_C1)", "v(a)"]);
        assert_eq!(t.len(), 4);
        assert_eq!(t.get(VarId::new(0)), "u_R1");
        assert_eq!(t.get(VarId::new(1)), "");
        assert_eq!(t.get(VarId::new(2)), "der(u_C1)");
        assert_eq!(t.get(VarId::new(3)), "v(a)");
        assert_eq!(t.get(VarId::new(9)), "");
    }
}
