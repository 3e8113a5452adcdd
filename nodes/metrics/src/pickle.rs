//! A small Python pickle reader for checkpoints made of nested dicts of numpy arrays.
//!
//! It runs the pickle virtual machine over protocols 2–5 (the opcodes such files use: dicts,
//! lists, tuples, strings, bytes, ints, floats, booleans, `None`, memo access, `GLOBAL` /
//! `STACK_GLOBAL`, `REDUCE`, `BUILD`, `FRAME`) and understands exactly these callables:
//! `numpy.core.multiarray._reconstruct` (also `numpy._core…`), `numpy.ndarray`, `numpy.dtype`,
//! `_codecs.encode` (protocol-2 bytes) and `collections.OrderedDict`. Arrays must be float32
//! (little-endian); Fortran-ordered data is reordered to C order. Anything else is a clear error
//! naming the opcode or global and its byte offset; nothing is executed.

use std::collections::HashMap;

/// A decoded pickle value.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    /// `None`.
    None,
    /// `True` / `False`.
    Bool(bool),
    /// An integer that fits in i64.
    Int(i64),
    /// A float.
    Float(f64),
    /// A str.
    Str(String),
    /// A bytes object.
    Bytes(Vec<u8>),
    /// A tuple.
    Tuple(Vec<Value>),
    /// A list.
    List(Vec<Value>),
    /// A dict, in insertion order.
    Dict(Vec<(Value, Value)>),
    /// A float32 numpy array in C order.
    Array(Array),
    /// A reference to a supported global (callable) not yet applied.
    Global(Callable),
    /// A numpy dtype.
    Dtype(Dtype),
}

/// A float32 array in C (row-major) order.
#[derive(Clone, Debug, PartialEq)]
pub struct Array {
    /// The shape.
    pub shape: Vec<usize>,
    /// The values (empty until the array's state is set).
    pub data: Vec<f32>,
}

/// A numpy dtype as far as this reader cares.
#[derive(Clone, Debug, PartialEq)]
pub struct Dtype {
    /// Type code, e.g. "f4".
    pub code: String,
    /// Byte order character from the state ("<", ">", "|", "=").
    pub order: String,
}

/// The callables a pickle may reference.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Callable {
    /// `numpy.core.multiarray._reconstruct`.
    Reconstruct,
    /// `numpy.ndarray`.
    NdArray,
    /// `numpy.dtype`.
    Dtype,
    /// `_codecs.encode`.
    CodecsEncode,
    /// `collections.OrderedDict`.
    OrderedDict,
}

/// Parses a pickle; errors say what is unsupported and where.
pub fn load(bytes: &[u8]) -> Result<Value, String> {
    Vm {
        buf: bytes,
        pos: 0,
        stack: Vec::new(),
        marks: Vec::new(),
        memo: HashMap::new(),
    }
    .run()
}

/// Flattens nested string-keyed dicts of arrays into `"a/b/c" → array`, in file order.
pub fn flatten_arrays(value: &Value) -> Result<Vec<(String, Array)>, String> {
    fn walk(v: &Value, prefix: &str, out: &mut Vec<(String, Array)>) -> Result<(), String> {
        match v {
            Value::Dict(items) => {
                for (k, v) in items {
                    let Value::Str(k) = k else {
                        return Err(format!("dict key {k:?} under {prefix:?} is not a string"));
                    };
                    let path = if prefix.is_empty() {
                        k.clone()
                    } else {
                        format!("{prefix}/{k}")
                    };
                    walk(v, &path, out)?;
                }
                Ok(())
            }
            Value::Array(a) => {
                out.push((prefix.to_string(), a.clone()));
                Ok(())
            }
            other => Err(format!(
                "{prefix:?} holds {}, expected a dict or a float32 array",
                kind(other)
            )),
        }
    }
    let mut out = Vec::new();
    walk(value, "", &mut out)?;
    Ok(out)
}

fn kind(v: &Value) -> &'static str {
    match v {
        Value::None => "None",
        Value::Bool(_) => "a bool",
        Value::Int(_) => "an int",
        Value::Float(_) => "a float",
        Value::Str(_) => "a str",
        Value::Bytes(_) => "bytes",
        Value::Tuple(_) => "a tuple",
        Value::List(_) => "a list",
        Value::Dict(_) => "a dict",
        Value::Array(_) => "an array",
        Value::Global(_) => "a global",
        Value::Dtype(_) => "a dtype",
    }
}

struct Vm<'a> {
    buf: &'a [u8],
    pos: usize,
    stack: Vec<Value>,
    marks: Vec<usize>,
    memo: HashMap<u64, Value>,
}

impl<'a> Vm<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&e| e <= self.buf.len())
            .ok_or_else(|| format!("truncated pickle: {n} bytes wanted at offset {}", self.pos))?;
        let s = &self.buf[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }
    fn u16(&mut self) -> Result<u16, String> {
        let b = self.take(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    fn u32(&mut self) -> Result<u32, String> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn u64(&mut self) -> Result<u64, String> {
        let b = self.take(8)?;
        Ok(u64::from_le_bytes(b.try_into().expect("8 bytes")))
    }
    fn line(&mut self) -> Result<String, String> {
        let rest = &self.buf[self.pos..];
        let n = rest
            .iter()
            .position(|&c| c == b'\n')
            .ok_or_else(|| format!("unterminated text argument at offset {}", self.pos))?;
        let s = String::from_utf8_lossy(&rest[..n]).into_owned();
        self.pos += n + 1;
        Ok(s)
    }
    fn utf8(&mut self, n: usize) -> Result<String, String> {
        let at = self.pos;
        String::from_utf8(self.take(n)?.to_vec())
            .map_err(|_| format!("invalid UTF-8 string at offset {at}"))
    }
    fn pop(&mut self) -> Result<Value, String> {
        self.stack
            .pop()
            .ok_or_else(|| format!("stack underflow at offset {}", self.pos))
    }
    fn top(&mut self) -> Result<&mut Value, String> {
        let pos = self.pos;
        self.stack
            .last_mut()
            .ok_or_else(|| format!("stack underflow at offset {pos}"))
    }
    fn pop_mark(&mut self) -> Result<Vec<Value>, String> {
        let m = self
            .marks
            .pop()
            .ok_or_else(|| format!("no MARK on the stack at offset {}", self.pos))?;
        if m > self.stack.len() {
            return Err(format!("MARK above the stack at offset {}", self.pos));
        }
        Ok(self.stack.split_off(m))
    }
    fn memo_get(&self, i: u64) -> Result<Value, String> {
        self.memo
            .get(&i)
            .cloned()
            .ok_or_else(|| format!("memo entry {i} missing at offset {}", self.pos))
    }

    fn run(mut self) -> Result<Value, String> {
        loop {
            let at = self.pos;
            let op = self.u8()?;
            match op {
                0x80 => {
                    let proto = self.u8()?;
                    if !(2..=5).contains(&proto) {
                        return Err(format!("pickle protocol {proto} is not supported (2–5)"));
                    }
                }
                0x95 => {
                    self.u64()?; // FRAME: length only, the data follows inline
                }
                b'.' => return self.pop(),
                b'(' => self.marks.push(self.stack.len()),
                b'0' => {
                    self.pop()?;
                }
                b'}' => self.stack.push(Value::Dict(Vec::new())),
                b']' => self.stack.push(Value::List(Vec::new())),
                b')' => self.stack.push(Value::Tuple(Vec::new())),
                b'N' => self.stack.push(Value::None),
                0x88 => self.stack.push(Value::Bool(true)),
                0x89 => self.stack.push(Value::Bool(false)),
                b'J' => {
                    let v = self.u32()? as i32;
                    self.stack.push(Value::Int(v as i64));
                }
                b'K' => {
                    let v = self.u8()?;
                    self.stack.push(Value::Int(v as i64));
                }
                b'M' => {
                    let v = self.u16()?;
                    self.stack.push(Value::Int(v as i64));
                }
                0x8a => {
                    let n = self.u8()? as usize;
                    let b = self.take(n)?;
                    if n > 8 {
                        return Err(format!("LONG1 of {n} bytes at offset {at} is too large"));
                    }
                    let mut v: i64 = 0;
                    for (i, &byte) in b.iter().enumerate() {
                        v |= (byte as i64) << (8 * i);
                    }
                    if n > 0 && n < 8 && b[n - 1] & 0x80 != 0 {
                        v -= 1i64 << (8 * n);
                    }
                    self.stack.push(Value::Int(v));
                }
                b'G' => {
                    let b = self.take(8)?;
                    self.stack
                        .push(Value::Float(f64::from_be_bytes(b.try_into().expect("8"))));
                }
                b'X' => {
                    let n = self.u32()? as usize;
                    let s = self.utf8(n)?;
                    self.stack.push(Value::Str(s));
                }
                0x8c => {
                    let n = self.u8()? as usize;
                    let s = self.utf8(n)?;
                    self.stack.push(Value::Str(s));
                }
                0x8d => {
                    let n = self.u64()? as usize;
                    let s = self.utf8(n)?;
                    self.stack.push(Value::Str(s));
                }
                b'B' => {
                    let n = self.u32()? as usize;
                    let b = self.take(n)?.to_vec();
                    self.stack.push(Value::Bytes(b));
                }
                b'C' => {
                    let n = self.u8()? as usize;
                    let b = self.take(n)?.to_vec();
                    self.stack.push(Value::Bytes(b));
                }
                0x8e => {
                    let n = self.u64()? as usize;
                    let b = self.take(n)?.to_vec();
                    self.stack.push(Value::Bytes(b));
                }
                // Python-2 str: raw bytes.
                b'T' => {
                    let n = self.u32()? as usize;
                    let b = self.take(n)?.to_vec();
                    self.stack.push(Value::Bytes(b));
                }
                b'U' => {
                    let n = self.u8()? as usize;
                    let b = self.take(n)?.to_vec();
                    self.stack.push(Value::Bytes(b));
                }
                b't' => {
                    let items = self.pop_mark()?;
                    self.stack.push(Value::Tuple(items));
                }
                0x85..=0x87 => {
                    let n = (op - 0x84) as usize;
                    if self.stack.len() < n {
                        return Err(format!("stack underflow at offset {at}"));
                    }
                    let items = self.stack.split_off(self.stack.len() - n);
                    self.stack.push(Value::Tuple(items));
                }
                b'l' => {
                    let items = self.pop_mark()?;
                    self.stack.push(Value::List(items));
                }
                b'd' => {
                    let items = self.pop_mark()?;
                    let d = pairs(items, at)?;
                    self.stack.push(Value::Dict(d));
                }
                b'a' => {
                    let v = self.pop()?;
                    match self.top()? {
                        Value::List(l) => l.push(v),
                        other => return Err(format!("APPEND to {} at offset {at}", kind(other))),
                    }
                }
                b'e' => {
                    let items = self.pop_mark()?;
                    match self.top()? {
                        Value::List(l) => l.extend(items),
                        other => return Err(format!("APPENDS to {} at offset {at}", kind(other))),
                    }
                }
                b's' => {
                    let v = self.pop()?;
                    let k = self.pop()?;
                    match self.top()? {
                        Value::Dict(d) => d.push((k, v)),
                        other => return Err(format!("SETITEM on {} at offset {at}", kind(other))),
                    }
                }
                b'u' => {
                    let items = self.pop_mark()?;
                    let kv = pairs(items, at)?;
                    match self.top()? {
                        Value::Dict(d) => d.extend(kv),
                        other => return Err(format!("SETITEMS on {} at offset {at}", kind(other))),
                    }
                }
                b'q' => {
                    let i = self.u8()? as u64;
                    let v = self.top()?.clone();
                    self.memo.insert(i, v);
                }
                b'r' => {
                    let i = self.u32()? as u64;
                    let v = self.top()?.clone();
                    self.memo.insert(i, v);
                }
                0x94 => {
                    let i = self.memo.len() as u64;
                    let v = self.top()?.clone();
                    self.memo.insert(i, v);
                }
                b'h' => {
                    let i = self.u8()? as u64;
                    let v = self.memo_get(i)?;
                    self.stack.push(v);
                }
                b'j' => {
                    let i = self.u32()? as u64;
                    let v = self.memo_get(i)?;
                    self.stack.push(v);
                }
                b'c' => {
                    let module = self.line()?;
                    let name = self.line()?;
                    self.stack.push(Value::Global(global(&module, &name, at)?));
                }
                0x93 => {
                    let name = self.pop()?;
                    let module = self.pop()?;
                    match (module, name) {
                        (Value::Str(m), Value::Str(n)) => {
                            self.stack.push(Value::Global(global(&m, &n, at)?))
                        }
                        _ => return Err(format!("STACK_GLOBAL without strings at offset {at}")),
                    }
                }
                b'R' => {
                    let args = self.pop()?;
                    let func = self.pop()?;
                    let v = reduce(func, args, at)?;
                    self.stack.push(v);
                }
                0x81 => {
                    // NEWOBJ: cls.__new__(cls, *args); only OrderedDict is meaningful here.
                    let args = self.pop()?;
                    let cls = self.pop()?;
                    let v = reduce(cls, args, at)?;
                    self.stack.push(v);
                }
                b'b' => {
                    let state = self.pop()?;
                    let obj = self.pop()?;
                    self.stack.push(build(obj, state, at)?);
                }
                other => {
                    return Err(format!(
                        "unsupported pickle opcode 0x{other:02x} ({:?}) at offset {at}",
                        other as char
                    ))
                }
            }
        }
    }
}

fn pairs(items: Vec<Value>, at: usize) -> Result<Vec<(Value, Value)>, String> {
    if !items.len().is_multiple_of(2) {
        return Err(format!("odd number of dict items at offset {at}"));
    }
    let mut out = Vec::with_capacity(items.len() / 2);
    let mut it = items.into_iter();
    while let (Some(k), Some(v)) = (it.next(), it.next()) {
        out.push((k, v));
    }
    Ok(out)
}

fn global(module: &str, name: &str, at: usize) -> Result<Callable, String> {
    Ok(match (module, name) {
        ("numpy.core.multiarray" | "numpy._core.multiarray", "_reconstruct") => {
            Callable::Reconstruct
        }
        ("numpy", "ndarray") => Callable::NdArray,
        ("numpy", "dtype") => Callable::Dtype,
        ("_codecs", "encode") => Callable::CodecsEncode,
        ("collections", "OrderedDict") => Callable::OrderedDict,
        _ => {
            return Err(format!(
                "unsupported pickle global {module}.{name} at offset {at} (only numpy arrays \
                 in nested dicts are read)"
            ))
        }
    })
}

fn reduce(func: Value, args: Value, at: usize) -> Result<Value, String> {
    let Value::Global(f) = func else {
        return Err(format!("REDUCE on {} at offset {at}", kind(&func)));
    };
    let Value::Tuple(args) = args else {
        return Err(format!(
            "REDUCE arguments are {} at offset {at}",
            kind(&args)
        ));
    };
    match (f, args.as_slice()) {
        (Callable::Reconstruct, [Value::Global(Callable::NdArray), ..]) => {
            Ok(Value::Array(Array {
                shape: Vec::new(),
                data: Vec::new(),
            }))
        }
        (Callable::Dtype, [Value::Str(code), ..]) => Ok(Value::Dtype(Dtype {
            code: code.clone(),
            order: "=".into(),
        })),
        (Callable::CodecsEncode, [Value::Str(s), Value::Str(enc)])
            if enc.eq_ignore_ascii_case("latin1") || enc.eq_ignore_ascii_case("latin-1") =>
        {
            s.chars()
                .map(|c| u8::try_from(c as u32).map_err(|_| c))
                .collect::<Result<Vec<u8>, char>>()
                .map(Value::Bytes)
                .map_err(|c| format!("character {c:?} is not latin-1 at offset {at}"))
        }
        (Callable::OrderedDict, []) => Ok(Value::Dict(Vec::new())),
        (f, a) => Err(format!(
            "unsupported call {f:?} with {} argument(s) at offset {at}",
            a.len()
        )),
    }
}

fn as_usize(v: &Value) -> Option<usize> {
    match v {
        Value::Int(i) if *i >= 0 => Some(*i as usize),
        _ => None,
    }
}

fn build(obj: Value, state: Value, at: usize) -> Result<Value, String> {
    match obj {
        Value::Dtype(mut d) => {
            // state = (version, byteorder, subarray, names, fields, elsize, alignment, flags)
            if let Value::Tuple(s) = &state {
                if let Some(Value::Str(order)) = s.get(1) {
                    d.order = order.clone();
                }
            }
            Ok(Value::Dtype(d))
        }
        Value::Array(_) => {
            // state = (version, shape, dtype, is_fortran, raw data)
            let Value::Tuple(s) = state else {
                return Err(format!("array state is {} at offset {at}", kind(&state)));
            };
            let [_, Value::Tuple(shape), Value::Dtype(dtype), Value::Bool(fortran), raw] =
                s.as_slice()
            else {
                return Err(format!(
                    "unexpected numpy array state layout at offset {at}"
                ));
            };
            let shape: Vec<usize> = shape
                .iter()
                .map(as_usize)
                .collect::<Option<_>>()
                .ok_or_else(|| format!("bad array shape at offset {at}"))?;
            let little = matches!(dtype.order.as_str(), "<" | "|")
                || (dtype.order == "=" && cfg!(target_endian = "little"));
            if dtype.code != "f4" || !little {
                return Err(format!(
                    "array of dtype {}{} at offset {at}: only little-endian float32 is supported",
                    dtype.order, dtype.code
                ));
            }
            let Value::Bytes(raw) = raw else {
                return Err(format!("array data is {} at offset {at}", kind(raw)));
            };
            let n: usize = shape.iter().product();
            if raw.len() != n * 4 {
                return Err(format!(
                    "array of shape {shape:?} has {} data bytes, expected {} (offset {at})",
                    raw.len(),
                    n * 4
                ));
            }
            let vals: Vec<f32> = raw
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            let data = if *fortran && shape.len() > 1 {
                fortran_to_c(&vals, &shape)
            } else {
                vals
            };
            Ok(Value::Array(Array { shape, data }))
        }
        other => Err(format!("BUILD on {} at offset {at}", kind(&other))),
    }
}

/// Reorders column-major (Fortran) data of `shape` to row-major.
fn fortran_to_c(vals: &[f32], shape: &[usize]) -> Vec<f32> {
    let n = vals.len();
    let mut out = vec![0f32; n];
    let mut idx = vec![0usize; shape.len()];
    for v in out.iter_mut() {
        // Fortran offset of the current C-order multi-index.
        let mut off = 0;
        let mut stride = 1;
        for (d, &i) in idx.iter().enumerate() {
            off += i * stride;
            stride *= shape[d];
        }
        *v = vals[off];
        for d in (0..shape.len()).rev() {
            idx[d] += 1;
            if idx[d] < shape[d] {
                break;
            }
            idx[d] = 0;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Hand-assembled protocol-3 pickle of `{"a": {"k": np.arange(6, dtype=f4).reshape(2, 3)}}`
    /// in the layout numpy writes, with the data given Fortran-ordered.
    fn sample(fortran: bool) -> Vec<u8> {
        let mut p = vec![0x80, 3, b'}', b'q', 0, b'('];
        let s = |p: &mut Vec<u8>, t: &str| {
            p.push(b'X');
            p.extend((t.len() as u32).to_le_bytes());
            p.extend(t.as_bytes());
        };
        s(&mut p, "a");
        p.extend([b'}', b'(']);
        s(&mut p, "k");
        p.extend(b"cnumpy.core.multiarray\n_reconstruct\nq\x01cnumpy\nndarray\nq\x02K\x00\x85C\x01b\x87R");
        p.extend(b"(K\x01K\x02K\x03\x86cnumpy\ndtype\nX\x02\x00\x00\x00f4\x89\x88\x87R");
        p.extend(b"(K\x03X\x01\x00\x00\x00<NNNJ\xff\xff\xff\xffJ\xff\xff\xff\xffK\x00tb");
        p.push(if fortran { 0x88 } else { 0x89 });
        let vals: Vec<f32> = if fortran {
            vec![0., 3., 1., 4., 2., 5.]
        } else {
            vec![0., 1., 2., 3., 4., 5.]
        };
        p.push(b'B');
        p.extend(24u32.to_le_bytes());
        for v in vals {
            p.extend(v.to_le_bytes());
        }
        p.extend([b't', b'b', b'u', b'u', b'.']);
        p
    }

    #[test]
    fn reads_nested_arrays() {
        for fortran in [false, true] {
            let v = load(&sample(fortran)).unwrap();
            let flat = flatten_arrays(&v).unwrap();
            assert_eq!(flat.len(), 1);
            assert_eq!(flat[0].0, "a/k");
            assert_eq!(flat[0].1.shape, vec![2, 3]);
            assert_eq!(flat[0].1.data, vec![0., 1., 2., 3., 4., 5.]);
        }
    }

    #[test]
    fn rejects_unknown_content() {
        let e = load(b"\x80\x03cos\nsystem\n.").unwrap_err();
        assert!(e.contains("os.system"), "{e}");
        let e = load(b"\x80\x03I1\n.").unwrap_err();
        assert!(e.contains("opcode 0x49"), "{e}");
        let mut truncated = sample(false);
        truncated.truncate(truncated.len() - 30);
        assert!(load(&truncated).is_err());
        let e = load(b"\x80\x01.").unwrap_err();
        assert!(e.contains("protocol 1"), "{e}");
    }
}
