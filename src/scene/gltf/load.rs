//! Reading a glTF file and the files it names, bounded and checked before
//! any accessor is read: the `gltf` crate's own importer reads whatever a
//! URI names (`/dev/zero`, a FIFO), decodes every image whether used or not,
//! and panics on some malformed input (a bad percent escape, an image view
//! past its buffer, an unexpected component type).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use gltf::accessor::{DataType, Dimensions};

use crate::scene::SceneError;
use crate::scene::error::error;

/// Most elements one accessor may hold (2²⁴ vertices, indices or keys).
pub(super) const MAX_ACCESSOR: usize = 1 << 24;
/// Largest file (the glTF itself, a buffer or an image) read, in bytes.
const MAX_FILE: u64 = crate::limits::MAX_INPUT_FILE;

/// A parsed file: the document, its buffers, and its images.
pub(super) struct Loaded {
    pub(super) doc: gltf::Document,
    pub(super) buffers: Vec<gltf::buffer::Data>,
    pub(super) images: Images,
}

/// The file's images, each decoded once, on first use.
pub(super) struct Images {
    /// Where relative URIs resolve.
    base: PathBuf,
    decoded: HashMap<usize, gltf::image::Data>,
}

/// Reads a regular file of at most [`MAX_FILE`] bytes
/// ([`crate::limits::read_regular`]: anything else is refused without
/// blocking); failing, an I/O error naming the file and where `named_by`
/// names it.
fn read_file(path: &Path, named_by: &Path, at: &str) -> Result<Vec<u8>, SceneError> {
    crate::limits::read_regular(path, MAX_FILE).map_err(|e| SceneError {
        unreadable: true,
        ..error(named_by, at, format!("cannot read `{}`: {e}", path.display()))
    })
}

/// The bytes of a `data:` URI (`data:[<media type>];base64,<data>`, the
/// form glTF allows), decoded by the `gltf` crate's own base64 reader
/// (`buffer::Data::from_source`, which zero-pads to a multiple of 4 bytes:
/// harmless after an image's end), as buffers' are. Used for images,
/// since the crate's image importer refuses any URI in a slice-only import
/// ("external reference", issue 42, §7). The decoded bytes are at most ¾
/// of the URI, which was read within [`MAX_FILE`] with its file.
fn data_uri(uri: &str) -> Result<Vec<u8>, String> {
    if !uri.starts_with("data:") || !uri.contains(";base64,") {
        return Err("a data: URI must be base64 (`data:<type>;base64,…`)".into());
    }
    gltf::buffer::Data::from_source(gltf::buffer::Source::Uri(uri), None)
        .map(|d| d.0)
        .map_err(|e| format!("cannot decode the data: URI: {e}"))
}

/// `%XX` escapes decoded; `None` for a bad escape or bytes that are not UTF-8.
fn percent_decode(uri: &str) -> Option<String> {
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = std::str::from_utf8(b.get(i + 1..i + 3)?).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// The file a non-`data:` URI names, relative to `base`.
fn uri_path(file: &Path, base: &Path, uri: &str, at: &str) -> Result<PathBuf, SceneError> {
    let local = if let Some(rest) = uri.strip_prefix("file://").or_else(|| uri.strip_prefix("file:")) {
        rest
    } else if uri.contains(':') {
        return Err(error(file, at, format!("URI `{uri}`: only relative paths, file: and data: URIs are read")));
    } else {
        uri
    };
    let decoded =
        percent_decode(local).ok_or_else(|| error(file, at, format!("URI `{uri}` has a bad percent escape")))?;
    Ok(base.join(decoded))
}

impl Loaded {
    /// Parses and validates the file at `path` and reads its buffers.
    pub(super) fn open(path: &Path) -> Result<Self, SceneError> {
        let bytes = read_file(path, path, "")?;
        // A GLB header's length below its own 12 bytes overflows a
        // subtraction in the gltf crate (found by fuzzing).
        if bytes.starts_with(b"glTF")
            && bytes.get(8..12).is_none_or(|l| u32::from_le_bytes([l[0], l[1], l[2], l[3]]) < 12)
        {
            return Err(error(path, "", "cannot read glTF: the GLB header's length is shorter than the header"));
        }
        let invalid = |e: gltf::Error| match e {
            gltf::Error::Validation(list) => {
                let (p, what) = &list[0];
                let more = if list.len() > 1 { format!(" (and {} more)", list.len() - 1) } else { String::new() };
                error(path, super::pointer(&p.to_string()), format!("invalid glTF: {what}{more}"))
            }
            other => error(path, "", format!("cannot read glTF: {other}")),
        };
        let gltf = gltf::Gltf::from_slice_without_validation(&bytes).map_err(invalid)?;
        // The validator indexes a primitive's POSITION accessor before it
        // checks the index (a panic in gltf-json, found by fuzzing).
        let root = gltf.document.into_json();
        for (m, mesh) in root.meshes.iter().enumerate() {
            for (k, prim) in mesh.primitives.iter().enumerate() {
                for (semantic, index) in &prim.attributes {
                    if index.value() >= root.accessors.len() {
                        let name = match semantic {
                            gltf::json::validation::Checked::Valid(s) => s.to_string(),
                            gltf::json::validation::Checked::Invalid => "?".into(),
                        };
                        return Err(error(
                            path,
                            format!("/meshes/{m}/primitives/{k}/attributes/{name}"),
                            format!("accessor {} does not exist", index.value()),
                        ));
                    }
                }
            }
        }
        // Nor does it check animation channels' targets (gltf-json 1.4.1
        // validates only their sampler index), which the reader unwraps.
        for (a, anim) in root.animations.iter().enumerate() {
            for (c, channel) in anim.channels.iter().enumerate() {
                let at = format!("/animations/{a}/channels/{c}/target");
                if channel.target.node.value() >= root.nodes.len() {
                    return Err(error(path, format!("{at}/node"), "no such node"));
                }
                if matches!(channel.target.path, gltf::json::validation::Checked::Invalid) {
                    return Err(error(path, format!("{at}/path"), "must be translation, rotation, scale or weights"));
                }
            }
        }
        let doc = gltf::Document::from_json(root).map_err(invalid)?;
        let gltf = gltf::Gltf { document: doc, blob: gltf.blob };
        drop(bytes);
        let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
        let mut blob = gltf.blob;
        let doc = gltf.document;
        let mut buffers = Vec::with_capacity(doc.buffers().len());
        for buffer in doc.buffers() {
            let at = format!("/buffers/{}", buffer.index());
            let mut data = match buffer.source() {
                gltf::buffer::Source::Bin => {
                    blob.take().ok_or_else(|| error(path, &at, "the GLB file has no binary chunk for this buffer"))?
                }
                gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
                    gltf::buffer::Data::from_source(buffer.source(), None)
                        .map_err(|e| error(path, format!("{at}/uri"), format!("cannot decode the data URI: {e}")))?
                        .0
                }
                gltf::buffer::Source::Uri(uri) => {
                    read_file(&uri_path(path, &base, uri, &format!("{at}/uri"))?, path, &format!("{at}/uri"))?
                }
            };
            if data.len() < buffer.length() {
                return Err(error(
                    path,
                    format!("{at}/byteLength"),
                    format!("{} bytes declared, {} present", buffer.length(), data.len()),
                ));
            }
            data.resize(data.len().next_multiple_of(4), 0);
            buffers.push(gltf::buffer::Data(data));
        }
        Ok(Self { doc, buffers, images: Images { base, decoded: HashMap::new() } })
    }
}

impl Images {
    /// Image `index`, decoded on first use as 8-bit RGB, through
    /// [`crate::scene::texture::decode_image`]: an image a texture cannot
    /// hold (a side beyond [`crate::limits::MAX_TEXTURE_SIDE`], more than
    /// [`crate::limits::MAX_TEXTURE_TEXELS`]) is refused naming it, before
    /// it is decoded.
    pub(super) fn get(
        &mut self,
        file: &Path,
        doc: &gltf::Document,
        buffers: &[gltf::buffer::Data],
        index: usize,
    ) -> Result<&gltf::image::Data, SceneError> {
        if !self.decoded.contains_key(&index) {
            let at = format!("/images/{index}");
            let img = doc.images().nth(index).ok_or_else(|| error(file, &at, "no such image"))?;
            // `Image::source` unwraps these (gltf 1.4.1).
            let raw = &doc.as_json().images[index];
            match (&raw.buffer_view, &raw.uri) {
                (Some(v), _) if v.value() >= doc.views().len() => {
                    return Err(error(file, format!("{at}/bufferView"), "no such buffer view"));
                }
                (Some(_), _) if raw.mime_type.is_none() => {
                    return Err(error(file, format!("{at}/mimeType"), "an image in a buffer view needs a mimeType"));
                }
                (None, None) => return Err(error(file, &at, "the image has neither a uri nor a bufferView")),
                _ => {}
            }
            let read;
            let bytes: &[u8] = match img.source() {
                gltf::image::Source::View { view, .. } => {
                    let data = &buffers[view.buffer().index()].0;
                    view.offset()
                        .checked_add(view.length())
                        .and_then(|end| data.get(view.offset()..end))
                        .ok_or_else(|| error(file, format!("{at}/bufferView"), "the view lies outside its buffer"))?
                }
                gltf::image::Source::Uri { uri, .. } if uri.starts_with("data:") => {
                    read = data_uri(uri).map_err(|e| error(file, format!("{at}/uri"), e))?;
                    &read
                }
                gltf::image::Source::Uri { uri, .. } => {
                    let p = uri_path(file, &self.base, uri, &format!("{at}/uri"))?;
                    read = read_file(&p, file, &format!("{at}/uri"))?;
                    &read
                }
            };
            let rgb = crate::scene::texture::decode_image(bytes)
                .map_err(|e| error(file, &at, format!("{}: {e}", image_name(raw, index))))?
                .into_rgb8();
            let (width, height) = rgb.dimensions();
            self.decoded.insert(
                index,
                gltf::image::Data { pixels: rgb.into_raw(), format: gltf::image::Format::R8G8B8, width, height },
            );
        }
        Ok(&self.decoded[&index])
    }
}

/// How an error names image `index`: its index, its name if it has one,
/// and its URI (not a `data:` URI's bytes) or buffer view.
fn image_name(raw: &gltf::json::Image, index: usize) -> String {
    let name = raw.name.as_ref().map_or(String::new(), |n| format!(" `{n}`"));
    let source = match (&raw.uri, &raw.buffer_view) {
        (Some(uri), _) if uri.starts_with("data:") => " (a data: URI)".to_string(),
        (Some(uri), _) => format!(" (`{uri}`)"),
        (None, Some(view)) => format!(" (buffer view {})", view.value()),
        (None, None) => String::new(),
    };
    format!("image {index}{name}{source}")
}

/// Checks an accessor before it is read: its component type and shape are
/// ones the reader handles (others reach `unreachable!` in the `gltf`
/// crate) and it holds at most [`MAX_ACCESSOR`] elements.
pub(super) fn check_accessor(
    file: &Path,
    accessor: &gltf::Accessor<'_>,
    types: &[DataType],
    dims: Dimensions,
    what: &str,
) -> Result<(), SceneError> {
    let at = format!("/accessors/{}", accessor.index());
    if !types.contains(&accessor.data_type()) || accessor.dimensions() != dims {
        return Err(error(
            file,
            at,
            format!(
                "{what}: {:?} {:?} is not a layout glTF allows here (expected {dims:?} of {types:?})",
                accessor.dimensions(),
                accessor.data_type()
            ),
        ));
    }
    // A count of 0 and a stride shorter than an element trip the gltf
    // crate's arithmetic and assertions (found by fuzzing); glTF forbids both.
    if accessor.count() == 0 {
        return Err(error(file, format!("{at}/count"), format!("{what}: an accessor holds at least one element")));
    }
    if let Some(stride) = accessor.view().and_then(|v| v.stride())
        && stride < accessor.size()
    {
        return Err(error(
            file,
            format!("/bufferViews/{}/byteStride", accessor.view().map_or(0, |v| v.index())),
            format!("{what}: a stride of {stride} bytes is shorter than an element ({} bytes)", accessor.size()),
        ));
    }
    if accessor.count() > MAX_ACCESSOR {
        return Err(error(file, format!("{at}/count"), format!("{what}: more than {MAX_ACCESSOR} elements")));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percent_escapes() {
        assert_eq!(percent_decode("a%20b.bin").as_deref(), Some("a b.bin"));
        assert_eq!(percent_decode("x%FF.bin"), None, "not UTF-8");
        assert_eq!(percent_decode("x%2"), None, "cut short");
        assert_eq!(percent_decode("x%zz"), None);
    }
}
