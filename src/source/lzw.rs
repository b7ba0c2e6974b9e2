//! TIFF's LZW (compression 5) decoded straight into a tile's bytes.
//!
//! Why our own and not `weezl` (the maintained crate, which `image` and `tiff` use and which our
//! tests still use as the reference encoder and decoder): a COG tile is decoded whole into a
//! buffer of known size, and there every string a code stands for already lies in the output, at
//! the place it was first written. So a code is one copy inside the output and the table holds only
//! where each string starts and how long it is. `weezl` serves streams: it
//! keeps its strings in its own table and walks a prefix chain for each code. Measured on GDAL's
//! LZW COGs of 256-texel RGB tiles (`clipbench cog --compression lzw`, docs/BENCHMARKS.md, COG),
//! `weezl` decoded at about 0.66 of GDAL's libtiff per tile, which put the 2x goal against GDAL
//! out of reach on 2 cores.
//!
//! Most strings are short (on a noisy texture, one to three bytes), so the loop is built for
//! them: a string of at most 16 bytes moves as one 16-byte load and store (the bytes written past
//! its end are written over by the strings that follow), a byte code takes the same path (its
//! value replaces the loaded bytes, so there is no branch on the kind of code), and the entry a
//! code makes is entered before the code is looked up, so that a code naming the entry being made
//! (LZW's "KwKwK" case) needs no path of its own, only its last byte set after. This doubled the
//! rate of the first version of this decoder (one `copy_within` a string, the table entered after
//! each code; kept in the tests as the oracle): on the 256 level-0 tiles of `clipbench cog
//! --quick`'s COG, one thread, from about 1 630 to 3 400 tiles a second.
//!
//! The format: codes are read most significant bit first, 9 bits wide at first; 256 clears the
//! table, 257 ends the data, new entries start at 258; the width grows one code early (TIFF's
//! "early change": to 10 bits once the next free code is 511, and so on) up to 12 bits.

const CLEAR: u16 = 256;
const END: u16 = 257;
const FIRST: usize = 258;
const MAX_CODES: usize = 4096;

/// Decodes `packed` into `out`; returns the bytes written, at most `out.len()` (the data may end
/// early; more data than `out` holds is cut at its end, as libtiff does).
pub(crate) fn decode(packed: &[u8], out: &mut [u8]) -> Result<usize, String> {
    if u32::try_from(out.len()).is_err() {
        return Err(format!("a {}-byte tile is past what one LZW strip or tile can hold here", out.len()));
    }
    // Each code's string: where it starts in `out` and its length. A byte (a code below 256) is a
    // string of length 1 at 0, whose bytes are loaded and then replaced by the code's value.
    let mut table = [(0u32, 1u32); MAX_CODES];
    let mut next = FIRST;
    let mut width = 9u32;
    // The previous code's string; `prev_len` 0 right after a clear (no previous string).
    let (mut prev_start, mut prev_len) = (0usize, 0usize);
    let mut pos = 0usize;
    let (mut bits, mut nbits, mut at) = (0u64, 0u32, 0usize);
    while pos < out.len() {
        if nbits < width {
            if let Some(word) = packed.get(at..at + 8) {
                // Eight bytes at once; the bytes past those counted are loaded again, to the
                // same bits, by the next refill.
                bits |= u64::from_be_bytes(word.try_into().expect("eight bytes")) >> nbits;
                let take = (63 - nbits) / 8;
                at += take as usize;
                nbits += take * 8;
            } else {
                while nbits <= 56 && at < packed.len() {
                    bits |= (packed[at] as u64) << (56 - nbits);
                    nbits += 8;
                    at += 1;
                }
                if nbits < width {
                    // The data ends without an end code: what is decoded stands.
                    break;
                }
            }
        }
        let code = (bits >> (64 - width)) as usize;
        bits <<= width;
        nbits -= width;
        if code == CLEAR as usize {
            next = FIRST;
            width = 9;
            prev_len = 0;
            continue;
        }
        if code == END as usize {
            break;
        }
        // The next code stands for the previous string and the first byte of this one, which
        // lie side by side in `out`: entered before this code is looked up, so that a code
        // naming the entry being made (LZW's "KwKwK") finds it too.
        let defining = code == next;
        if code > next || (defining && prev_len == 0) {
            return Err(if defining {
                format!("code {code} comes before any string it could extend")
            } else {
                format!("code {code} where the table holds codes up to {}", next - 1)
            });
        }
        if prev_len != 0 && next < MAX_CODES {
            table[next] = (prev_start as u32, (prev_len + 1) as u32);
            next += 1;
            if next + 1 >= (1 << width) && width < 12 {
                width += 1;
            }
        }
        // Codes are at most 12 bits: within the table.
        let (start, len) = table[code & (MAX_CODES - 1)];
        let (start, len) = (start as usize, len as usize);
        let here = pos;
        if len <= 16 && pos + 16 <= out.len() {
            // The common case: a short string, moved as 16 bytes through a register (the bytes
            // past its length are written over by the strings that follow). Its bytes lie before
            // `pos`, all but the last of a string being defined, which is set after.
            let word: [u8; 16] = out[start..start + 16].try_into().expect("sixteen bytes");
            let word = if code < 256 { code as u128 } else { u128::from_le_bytes(word) };
            out[pos..pos + 16].copy_from_slice(&word.to_le_bytes());
            if defining {
                out[pos + len - 1] = out[start];
            }
            pos += len;
        } else {
            let n = len.min(out.len() - pos);
            if code < 256 {
                out[pos] = code as u8;
            } else {
                out.copy_within(start..start + n, pos);
                if defining && n == len {
                    out[pos + len - 1] = out[start];
                }
            }
            pos += n;
        }
        (prev_start, prev_len) = (here, pos - here);
    }
    Ok(pos)
}

#[cfg(test)]
mod tests {
    use super::{decode, CLEAR, END, FIRST, MAX_CODES};
    use proptest::prelude::*;

    /// The plain decoder (one code at a time, every string copied with `copy_within`, the table
    /// entered after each code, no bytes written past a string): the oracle of the fast one.
    fn plain_decode(packed: &[u8], out: &mut [u8]) -> Result<usize, String> {
        if u32::try_from(out.len()).is_err() {
            return Err(format!("a {}-byte tile is past what one LZW strip or tile can hold here", out.len()));
        }
        // Where each code's string starts in `out`, and its length; codes below 256 are bytes.
        let mut start = vec![0u32; MAX_CODES];
        let mut len = vec![0u32; MAX_CODES];
        let mut next = FIRST;
        let mut width = 9u32;
        // The previous code's string (start, length), `None` right after a clear.
        let mut prev: Option<(usize, usize)> = None;
        let mut pos = 0usize;
        let (mut bits, mut nbits, mut at) = (0u64, 0u32, 0usize);
        while pos < out.len() {
            if nbits < width {
                if let Some(word) = packed.get(at..at + 8) {
                    // Eight bytes at once; the bytes past those counted are loaded again, to the
                    // same bits, by the next refill.
                    bits |= u64::from_be_bytes(word.try_into().expect("eight bytes")) >> nbits;
                    let take = (63 - nbits) / 8;
                    at += take as usize;
                    nbits += take * 8;
                } else {
                    while nbits <= 56 && at < packed.len() {
                        bits |= (packed[at] as u64) << (56 - nbits);
                        nbits += 8;
                        at += 1;
                    }
                }
            }
            if nbits < width {
                // The data ends without an end code: what is decoded stands.
                break;
            }
            let code = (bits >> (64 - width)) as u16;
            bits <<= width;
            nbits -= width;
            if code == CLEAR {
                next = FIRST;
                width = 9;
                prev = None;
                continue;
            }
            if code == END {
                break;
            }
            let c = code as usize;
            let here = pos;
            let n = if c < 256 {
                out[pos] = c as u8;
                1
            } else if c < next && c >= FIRST {
                let (s, n) = (start[c] as usize, len[c] as usize);
                let n = n.min(out.len() - pos);
                out.copy_within(s..s + n, pos);
                n
            } else if c == next {
                // The string being defined: the previous one and its own first byte.
                let Some((ps, pn)) = prev else {
                    return Err(format!("code {c} comes before any string it could extend"));
                };
                let n = pn.min(out.len() - pos);
                out.copy_within(ps..ps + n, pos);
                if n == pn && pos + n < out.len() {
                    out[pos + n] = out[ps];
                    n + 1
                } else {
                    n
                }
            } else {
                return Err(format!("code {c} where the table holds codes up to {}", next - 1));
            };
            pos += n;
            if let Some((ps, pn)) = prev {
                if next < MAX_CODES {
                    // The previous string and the first byte of this one: they lie side by side.
                    start[next] = ps as u32;
                    len[next] = (pn + 1) as u32;
                    next += 1;
                    if next + 1 >= (1 << width) && width < 12 {
                        width += 1;
                    }
                }
            }
            prev = Some((here, n));
        }
        Ok(pos)
    }

    fn packed(data: &[u8]) -> Vec<u8> {
        weezl::encode::Encoder::with_tiff_size_switch(weezl::BitOrder::Msb, 8).encode(data).unwrap()
    }

    fn weezl_decode(p: &[u8], n: usize) -> Vec<u8> {
        let mut out = vec![0u8; n];
        let mut d = weezl::decode::Decoder::with_tiff_size_switch(weezl::BitOrder::Msb, 8);
        let (mut inp, mut done) = (p, 0);
        while done < n {
            let r = d.decode_bytes(inp, &mut out[done..]);
            inp = &inp[r.consumed_in..];
            done += r.consumed_out;
            if !matches!(r.status, Ok(weezl::LzwStatus::Ok)) || r.consumed_in + r.consumed_out == 0 {
                break;
            }
        }
        out.truncate(done);
        out
    }

    #[test]
    fn long_runs_and_every_byte_value_round_trip_through_table_resets() {
        // A run (the KwKwK case again and again), every byte value, and enough data to fill the
        // 4096-code table several times (the encoder clears it).
        let mut data = vec![7u8; 5000];
        data.extend((0..=255u8).cycle().take(70_000));
        let mut x = 1u32;
        data.extend((0..200_000).map(|_| {
            x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (x >> 29) as u8
        }));
        let p = packed(&data);
        let mut out = vec![0u8; data.len()];
        assert_eq!(decode(&p, &mut out), Ok(data.len()));
        assert!(out == data, "the decoded bytes differ");
    }

    #[test]
    fn a_short_buffer_is_filled_and_the_rest_cut() {
        let data: Vec<u8> = (0..1000u32).map(|i| (i % 13) as u8).collect();
        let p = packed(&data);
        let mut out = vec![0u8; 600];
        assert_eq!(decode(&p, &mut out), Ok(600));
        assert_eq!(&out[..], &data[..600]);
    }

    #[test]
    fn a_code_past_the_table_is_an_error_not_a_panic() {
        // 9-bit codes: 65 ('A'), then 300 with only 258 defined next.
        let codes = [65u16, 300];
        let mut bits = 0u32;
        let mut bytes = Vec::new();
        let mut n = 0;
        for c in codes {
            bits = (bits << 9) | c as u32;
            n += 9;
            while n >= 8 {
                bytes.push((bits >> (n - 8)) as u8);
                n -= 8;
            }
        }
        bytes.push((bits << (8 - n)) as u8);
        let mut out = vec![0u8; 16];
        let e = decode(&bytes, &mut out).unwrap_err();
        assert!(e.contains("code 300"), "{e}");
    }

    proptest! {
        #[test]
        fn agrees_with_weezl_on_any_data(data in proptest::collection::vec(prop_oneof![Just(0u8), Just(1u8), any::<u8>()], 0..20_000)) {
            let p = packed(&data);
            let mut out = vec![0u8; data.len()];
            let n = decode(&p, &mut out).unwrap();
            prop_assert_eq!(n, data.len());
            prop_assert!(out == data, "our decode differs from the data");
            prop_assert!(weezl_decode(&p, data.len()) == data, "weezl's decode differs from the data");
        }

        #[test]
        /// Any bytes at all (garbage, or a valid stream with bits flipped) decode as the plain
        /// decoder decodes them: the same result, the same bytes, and never a panic.
        fn garbage_decodes_as_the_plain_decoder_does(
            bytes in proptest::collection::vec(any::<u8>(), 0..4000),
            n in 0usize..9000,
        ) {
            let (mut fast, mut plain) = (vec![0u8; n], vec![0u8; n]);
            let got = decode(&bytes, &mut fast);
            prop_assert_eq!(&got, &plain_decode(&bytes, &mut plain));
            if let Ok(k) = got {
                prop_assert!(k <= n);
                prop_assert!(fast[..k] == plain[..k]);
            }
        }

        #[test]
        fn a_damaged_stream_or_a_short_buffer_decodes_as_the_plain_decoder_does(
            data in proptest::collection::vec(prop_oneof![Just(0u8), Just(9u8), any::<u8>()], 1..20_000),
            flips in proptest::collection::vec(any::<usize>(), 0..4),
            cut in any::<usize>(),
        ) {
            let mut p = packed(&data);
            for f in flips {
                let bit = f % (8 * p.len());
                p[bit / 8] ^= 0x80 >> (bit % 8);
            }
            let n = cut % (data.len() + 1);
            let (mut fast, mut plain) = (vec![0u8; n], vec![0u8; n]);
            let got = decode(&p, &mut fast);
            prop_assert_eq!(&got, &plain_decode(&p, &mut plain));
            if let Ok(k) = got {
                prop_assert!(fast[..k] == plain[..k]);
            }
        }
    }
}
