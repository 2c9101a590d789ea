//! SCAFFOLD: replaced by the feed work.
use super::{FrameParser, ParseStats, RawFrame};
pub struct TextParser(ParseStats);
impl TextParser { pub fn new(_f: super::Format, _r: f64) -> Self { Self(Default::default()) } }
impl FrameParser for TextParser {
    fn parse(&mut self, _buf: &[u8], _out: &mut Vec<RawFrame>) -> usize { 0 }
    fn finish(&mut self, _tail: &[u8]) {}
    fn stats(&self) -> &ParseStats { &self.0 }
}
