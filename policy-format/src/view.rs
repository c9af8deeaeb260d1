//! Decoding and validating a policy file into a borrowed view.

use crate::body::{Body, BodyV1, LayerDtype, MAX_NAME_LEN};
use crate::error::{CapacityItem, FormatError};
use crate::header::{HEADER_LEN, Header, file_crc, layout_hash, values_offset};
use crate::int8;
use crate::weights::Values;

/// Compile-time limits of an evaluator, checked before a policy is accepted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Capacity {
    /// Largest observation dimension.
    pub max_obs: usize,
    /// Largest action dimension.
    pub max_act: usize,
    /// Widest layer.
    pub max_width: usize,
    /// Most layers.
    pub max_layers: usize,
}

/// Where one layer's numbers sit among the stored values (indices count 4-byte words).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LayerLayout {
    /// Input width.
    pub inputs: usize,
    /// Output width.
    pub outputs: usize,
    /// How the weights are stored.
    pub dtype: LayerDtype,
    /// Index of the first weight. f32: input-major, `w[i * outputs + j]` links input `i` to
    /// output `j`. int8: the first word of the packed weights ([`crate::int8`]).
    pub weights: usize,
    /// Index of the first per-output scale (int8 layers only).
    pub scales: Option<usize>,
    /// Index of the first bias.
    pub biases: usize,
}

/// A decoded, validated policy file borrowing from the file bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct PolicyView<'a> {
    header: Header,
    body: Body<'a>,
    values: Values<'a>,
}

impl<'a> PolicyView<'a> {
    /// Decodes and validates a whole file. Checks, in order: header length, magic, version, flags,
    /// announced sizes, CRC-32, padding, body, layout hash, layer chain, names, limits and
    /// finiteness of every stored value. Allocates nothing.
    pub fn decode(file: &'a [u8]) -> Result<Self, FormatError> {
        let header = Header::parse(file)?;
        let body_len = header.body_len as usize;
        let start = values_offset(body_len);
        let total = (header.value_count as usize)
            .checked_mul(4)
            .and_then(|n| n.checked_add(start))
            .ok_or(FormatError::Truncated {
                needed: usize::MAX,
                got: file.len(),
            })?;
        if file.len() < total {
            return Err(FormatError::Truncated {
                needed: total,
                got: file.len(),
            });
        }
        if file.len() > total {
            return Err(FormatError::TrailingBytes {
                expected: total,
                got: file.len(),
            });
        }
        let computed = file_crc(file);
        if computed != header.crc {
            return Err(FormatError::CrcMismatch {
                stored: header.crc,
                computed,
            });
        }
        let body_end = HEADER_LEN + body_len;
        if file[body_end..start].iter().any(|&b| b != 0) {
            return Err(FormatError::NonZeroPadding);
        }
        let body_bytes = &file[HEADER_LEN..body_end];
        let body: Body<'a> = if header.version == 1 {
            match postcard::take_from_bytes::<BodyV1<'a>>(body_bytes) {
                Ok((body, [])) => body.into(),
                _ => return Err(FormatError::MalformedBody),
            }
        } else {
            match postcard::take_from_bytes(body_bytes) {
                Ok((body, [])) => body,
                _ => return Err(FormatError::MalformedBody),
            }
        };
        let values = Values::new(&file[start..]);
        validate(&body, &values)?;
        let computed = body_layout_hash(&body);
        if computed != header.layout_hash {
            return Err(FormatError::LayoutHashMismatch {
                stored: header.layout_hash,
                computed,
            });
        }
        Ok(PolicyView {
            header,
            body,
            values,
        })
    }

    /// The fixed header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The decoded body.
    pub fn body(&self) -> &Body<'a> {
        &self.body
    }

    /// The stored values.
    pub fn values(&self) -> Values<'a> {
        self.values
    }

    /// Index of the first observation mean; means are followed by the same number of scales.
    /// A normalised observation is `clamp((x - mean) / scale, -clip, clip)`.
    pub fn normalisation_offset(&self) -> usize {
        0
    }

    /// Where layer `index` keeps its weights and biases.
    pub fn layer(&self, index: usize) -> Option<LayerLayout> {
        layer_layouts(&self.body).nth(index)
    }

    /// Layout of every layer, input to output.
    pub fn layers(&self) -> impl Iterator<Item = LayerLayout> + '_ {
        layer_layouts(&self.body)
    }

    /// The packed int8 weights of layer `index` ([`crate::int8`] layout); `None` for an f32 layer
    /// or an index past the last layer.
    pub fn int8_weights(&self, index: usize) -> Option<&'a [i8]> {
        let l = self.layer(index)?;
        if l.dtype != LayerDtype::Int8 {
            return None;
        }
        let len = int8::packed_bytes(l.inputs, l.outputs)?;
        self.values.int8(l.weights, len)
    }

    /// Bytes of stored weights (f32 and int8), without biases, scales and normalisation.
    pub fn weight_bytes(&self) -> usize {
        self.layers()
            .map(|l| match l.dtype {
                LayerDtype::F32 => l.inputs * l.outputs * 4,
                LayerDtype::Int8 => int8::packed_bytes(l.inputs, l.outputs).unwrap_or(0),
            })
            .sum()
    }

    /// Checks the policy against an evaluator's compile-time capacity.
    pub fn check_capacity(&self, cap: &Capacity) -> Result<(), FormatError> {
        let checks = [
            (CapacityItem::Observation, self.body.obs_dim(), cap.max_obs),
            (CapacityItem::Action, self.body.act_dim(), cap.max_act),
            (CapacityItem::Width, self.body.max_width(), cap.max_width),
            (CapacityItem::Layers, self.body.layers.len(), cap.max_layers),
        ];
        for (what, value, max) in checks {
            if value > max {
                return Err(FormatError::ExceedsCapacity { what, value, max });
            }
        }
        Ok(())
    }

    /// Checks that the policy's layouts equal the controller's: observation fields (name, size) and
    /// action joint names, in order.
    pub fn check_layout<'n>(
        &self,
        observation: impl IntoIterator<Item = (&'n str, usize)>,
        action: impl IntoIterator<Item = &'n str>,
    ) -> Result<(), FormatError> {
        let mut ours = self.body.observation.iter();
        let mut field = 0;
        for (name, size) in observation {
            match ours.next() {
                Some(f) if f.name == name && usize::from(f.size) == size => field += 1,
                _ => return Err(FormatError::ObservationLayoutMismatch { field }),
            }
        }
        if ours.next().is_some() {
            return Err(FormatError::ObservationLayoutMismatch { field });
        }
        let mut ours = self.body.action.iter();
        let mut joint = 0;
        for name in action {
            match ours.next() {
                Some(j) if j.name == name => joint += 1,
                _ => return Err(FormatError::ActionLayoutMismatch { joint }),
            }
        }
        if ours.next().is_some() {
            return Err(FormatError::ActionLayoutMismatch { joint });
        }
        Ok(())
    }
}

/// Layout hash of a body's observation and action layouts.
pub fn body_layout_hash(body: &Body<'_>) -> u32 {
    layout_hash(
        body.observation
            .iter()
            .map(|f| (f.name, usize::from(f.size))),
        body.action.iter().map(|j| j.name),
    )
}

fn layer_layouts<'b>(body: &'b Body<'_>) -> impl Iterator<Item = LayerLayout> + 'b {
    let obs = body.obs_dim();
    let mut inputs = obs;
    let mut next = 2 * obs;
    body.layers.iter().map(move |l| {
        let outputs = usize::from(l.outputs);
        let layout = match l.dtype {
            LayerDtype::F32 => LayerLayout {
                inputs,
                outputs,
                dtype: l.dtype,
                weights: next,
                scales: None,
                biases: next.saturating_add(inputs.saturating_mul(outputs)),
            },
            LayerDtype::Int8 => {
                let scales =
                    next.saturating_add(int8::packed_words(inputs, outputs).unwrap_or(usize::MAX));
                LayerLayout {
                    inputs,
                    outputs,
                    dtype: l.dtype,
                    weights: next,
                    scales: Some(scales),
                    biases: scales.saturating_add(outputs),
                }
            }
        };
        next = layout.biases.saturating_add(outputs);
        inputs = outputs;
        layout
    })
}

/// Checks everything about a body and its values that does not depend on a controller.
pub(crate) fn validate(body: &Body<'_>, values: &Values<'_>) -> Result<(), FormatError> {
    let name_ok = |n: &str| !n.is_empty() && n.len() <= MAX_NAME_LEN;
    for (field, f) in body.observation.iter().enumerate() {
        if !name_ok(f.name) {
            return Err(FormatError::BadName {
                max_len: MAX_NAME_LEN,
            });
        }
        if f.size == 0 {
            return Err(FormatError::EmptyObservationField { field });
        }
    }
    for (joint, j) in body.action.iter().enumerate() {
        if !name_ok(j.name) {
            return Err(FormatError::BadName {
                max_len: MAX_NAME_LEN,
            });
        }
        let finite = j.scale.is_finite() && j.min.is_finite() && j.max.is_finite();
        if !finite || j.min > j.max {
            return Err(FormatError::InvalidActionJoint { joint });
        }
    }
    if body.control_period_us == 0 {
        return Err(FormatError::InvalidControlPeriod);
    }
    if !(body.obs_clip.is_finite() && body.obs_clip > 0.0) {
        return Err(FormatError::InvalidNormalisation { index: usize::MAX });
    }
    if body.observation.is_empty() {
        return Err(FormatError::EmptyObservationField { field: 0 });
    }
    if body.layers.is_empty() {
        return Err(FormatError::EmptyLayer { layer: 0 });
    }
    if let Some(layer) = body.layers.iter().position(|l| l.outputs == 0) {
        return Err(FormatError::EmptyLayer { layer });
    }
    let outputs = body.layers.last().map_or(0, |l| usize::from(l.outputs));
    if outputs != body.act_dim() {
        return Err(FormatError::OutputMismatch {
            outputs,
            actions: body.act_dim(),
        });
    }
    let expected = body.stored_values().unwrap_or(usize::MAX);
    if expected != values.len() {
        return Err(FormatError::WeightCountMismatch {
            expected,
            stored: values.len(),
        });
    }
    // Every f32 word must be finite; packed int8 words are skipped.
    let mut int8_words = layer_layouts(body)
        .filter(|l| l.dtype == LayerDtype::Int8)
        .map(|l| l.weights..l.scales.unwrap_or(l.weights))
        .peekable();
    let mut index = 0;
    while index < values.len() {
        if let Some(skip) = int8_words.next_if(|skip| skip.start == index) {
            index = skip.end;
            continue;
        }
        if !values.get(index).is_some_and(f32::is_finite) {
            return Err(FormatError::NonFiniteWeight { index });
        }
        index += 1;
    }
    let obs = body.obs_dim();
    for index in obs..2 * obs {
        if !values.get(index).is_some_and(|s| s > 0.0) {
            return Err(FormatError::InvalidNormalisation { index: index - obs });
        }
    }
    for (layer, l) in layer_layouts(body).enumerate() {
        if l.dtype != LayerDtype::Int8 {
            continue;
        }
        let inputs = int8::padded(l.inputs);
        if inputs > int8::MAX_INPUTS {
            return Err(FormatError::QuantisedLayerTooWide {
                layer,
                inputs,
                max: int8::MAX_INPUTS,
            });
        }
        let scales = l.scales.unwrap_or(l.biases);
        if let Some(output) =
            (0..l.outputs).find(|&j| !values.get(scales + j).is_some_and(|s| s > 0.0))
        {
            return Err(FormatError::InvalidScale { layer, output });
        }
        let len = int8::packed_bytes(l.inputs, l.outputs).unwrap_or(usize::MAX);
        let packed = values
            .int8(l.weights, len)
            .ok_or(FormatError::WeightCountMismatch {
                expected,
                stored: values.len(),
            })?;
        let (in_pad, out_pad) = (int8::padded(l.inputs), int8::padded(l.outputs));
        let zero = |i: usize, j: usize| packed.get(int8::byte_index(l.inputs, i, j)) == Some(&0);
        let padding_ok = (l.outputs..out_pad).all(|j| (0..in_pad).all(|i| zero(i, j)))
            && (l.inputs..in_pad).all(|i| (0..l.outputs).all(|j| zero(i, j)));
        if !padding_ok {
            return Err(FormatError::NonZeroWeightPadding { layer });
        }
    }
    Ok(())
}
